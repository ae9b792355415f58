"""POST/GET /v1/targets/{target}/labelled-frames: frames with the optical observer's attitude, stored and listed."""

import io
from datetime import timedelta

import numpy as np
import pytest
from sqlalchemy import create_engine, func, select

from app.db.models import LabelledFrame
from app.schemas import PAPER_EXAMPLE
from app.services.scenes import scene_for, windows_of
from inference.labelled import coverage, write_frame
from inference.rotations import euler_from_matrix, euler_to_quaternion, geodesic_deg, rotation_matrix
from tests.conftest import KEY_A, KEY_B
from tests.utils.databases import store_campaign_row

A = {"X-API-Key": KEY_A}
B = {"X-API-Key": KEY_B}
T = "tiangong-like"


def _npz(seed, **label):
    rng = np.random.default_rng(seed)
    buf = io.BytesIO()
    write_frame(buf, rng.random((64, 64)) + 0.01, **label)
    return buf.getvalue()


def _post(client, files, headers=A, **form):
    return client.post(
        f"/v1/targets/{T}/labelled-frames",
        files=[("files", (name, data)) for name, data in files],
        data=form,
        headers=headers,
    )


def _count(settings):
    engine = create_engine(settings.database_url)
    with engine.connect() as conn:
        n = conn.scalar(select(func.count()).select_from(LabelledFrame))
    engine.dispose()
    return n


@pytest.fixture(scope="module")
def plan(client):
    return client.post("/v1/plans", json=PAPER_EXAMPLE, headers=A).json()


def test_frames_with_angles_are_stored_listed_and_not_stored_twice(client, settings):
    files = [
        ("a.npz", _npz(1, angles_deg=(10.0, -20.0, 30.0), scene="pass-1", snr_db=4.0)),
        ("b.npz", _npz(2, angles_deg=(-35.0, 5.0, 0.0), scene="pass-1")),
        ("c.npz", _npz(3, angles_deg=(1.0, 2.0, 3.0))),
    ]
    r = _post(client, files, scene="pass-2", attitude_sigma_deg="0.25")
    assert r.status_code == 201, r.text
    body = r.json()
    assert [f["name"] for f in body["stored"]] == ["a.npz", "b.npz", "c.npz"]
    assert [f["scene"] for f in body["stored"]] == ["pass-1", "pass-1", "pass-2"]  # the form's scene for c only
    assert body["stored"][0]["angles_deg"] == [10.0, -20.0, 30.0] and body["stored"][0]["snr_db"] == 4.0
    assert all(f["attitude_sigma_deg"] == 0.25 for f in body["stored"])
    assert body["per_scene"] == {"pass-1": 2, "pass-2": 1} and body["count"] == 3
    assert body["coverage"] == pytest.approx(coverage(np.array([[10, -20, 30], [-35, 5, 0], [1, 2, 3]])), abs=1e-4)
    again = _post(client, files[:1]).json()
    assert again["stored"] == [] and again["already_stored"] == ["a.npz"] and again["count"] == 3
    listed = client.get(f"/v1/targets/{T}/labelled-frames", params={"scene": "pass-1"}, headers=A).json()
    assert {f["name"] for f in listed["data"]} == {"a.npz", "b.npz"} and listed["count"] == 3
    # another operator sees none of them
    assert client.get(f"/v1/targets/{T}/labelled-frames", headers=B).json()["count"] == 0


def test_a_j2000_label_is_placed_by_the_plan(client, plan):
    w = windows_of(plan)[0]
    when = w.rise + (w.set - w.rise) / 2
    observation = scene_for(PAPER_EXAMPLE, when, when).placements([when]).observation[0]
    body_to_obs = rotation_matrix(12.0, -7.0, 3.0)
    q = euler_to_quaternion(*euler_from_matrix(observation @ body_to_obs))
    r = _post(
        client, [("q.npz", _npz(7, quaternion_j2000=q, observed_at=when.isoformat(), scene="j"))], plan_id=plan["id"]
    )
    assert r.status_code == 201, r.text
    got = r.json()["stored"][0]
    assert geodesic_deg(np.array(got["angles_deg"]), np.array([12.0, -7.0, 3.0]))[0] < 0.01
    assert got["plan_id"] == plan["id"] and got["station_name"] == plan["station_name"]
    assert np.allclose(got["quaternion_j2000"], q)


def test_a_j2000_label_is_placed_by_a_campaign(client, settings, plan):
    """A campaign's target and station place J2000 labels as a plan's do (its observer plays no part): a campaign
    row of the paper's target and station with the plan's windows stands in for one the campaign planner flew."""
    from app.core.security import key_fingerprint
    from app.db.models import Operator

    engine = create_engine(settings.database_url)
    with engine.connect() as conn:
        op_id = conn.scalar(select(Operator.id).where(Operator.name == f"env-{key_fingerprint(KEY_A)}"))
    engine.dispose()
    store_campaign_row(
        settings.database_url, campaign_id="camp-labels-1", operator_id=op_id, windows=plan["access_windows"], scenes=[]
    )
    w = windows_of(plan)[1]
    when = w.rise + (w.set - w.rise) / 3
    observation = scene_for(PAPER_EXAMPLE, when, when).placements([when]).observation[0]
    q = euler_to_quaternion(*euler_from_matrix(observation @ rotation_matrix(-20.0, 11.0, 4.0)))
    files = [("c.npz", _npz(8, quaternion_j2000=q, observed_at=when.isoformat(), scene="c"))]
    both = _post(client, files, plan_id=plan["id"], campaign_id="camp-labels-1")
    assert both.status_code == 422 and both.json()["detail"][0]["loc"][-1] == "campaign_id"
    assert _post(client, files, campaign_id="no-such-campaign").status_code == 422
    assert _post(client, files, headers=B, campaign_id="camp-labels-1").status_code == 422  # not B's
    r = _post(client, files, campaign_id="camp-labels-1")
    assert r.status_code == 201, r.text
    got = r.json()["stored"][0]
    assert geodesic_deg(np.array(got["angles_deg"]), np.array([-20.0, 11.0, 4.0]))[0] < 0.01
    assert got["campaign_id"] == "camp-labels-1" and got["plan_id"] is None and got["station_name"] == "GS"
    late = (w.set + timedelta(minutes=30)).isoformat()
    outside = _post(client, [("l.npz", _npz(9, quaternion_j2000=q, observed_at=late))], campaign_id="camp-labels-1")
    assert outside.status_code == 422 and outside.json()["detail"][0]["loc"][-1] == "observed_at"


@pytest.mark.parametrize(
    ("files", "form", "field", "says"),
    [
        ([("x.npz", b"not a zip")], {}, "file", "not a readable .npz"),
        ([("x.npz", _npz(1, angles_deg=(0, 95, 0)))], {}, "angles_deg", "y within"),
        (
            [("x.npz", _npz(1, quaternion_j2000=(1.0, 0.3, 0, 0), observed_at="2022-11-28T16:00:00Z"))],
            {},
            "quaternion_j2000",
            "unit norm",
        ),
        (
            [("x.npz", _npz(1, quaternion_j2000=(1.0, 0, 0, 0), observed_at="2022-11-28T16:00:00Z"))],
            {},
            "quaternion_j2000",
            "plan",
        ),
        ([("x.npz", _npz(1, angles_deg=(0, 0, 0)))], {"plan_id": "no-such-plan"}, "plan_id", "no plan"),
        ([("x.npz", _npz(1, angles_deg=(0, 0, 0)))], {"attitude_sigma_deg": "45"}, "attitude_sigma_deg", "10"),
    ],
)
def test_bad_frames_and_labels_are_refused_and_nothing_is_stored(client, settings, files, form, field, says):
    before = _count(settings)
    good = ("good.npz", _npz(99, angles_deg=(0.0, 0.0, 0.0)))
    r = _post(client, [good, *files], **form)
    assert r.status_code == 422, r.text
    detail = r.json()["detail"][0]
    assert field in [str(v) for v in detail["loc"]] and says in detail["msg"], detail
    assert _count(settings) == before


def test_times_outside_the_plan_and_a_plan_of_another_target(client, settings, plan):
    w = windows_of(plan)[0]
    outside = (w.rise.replace(year=w.rise.year - 1)).isoformat()
    q = euler_to_quaternion(0.0, 0.0, 0.0)
    r = _post(client, [("o.npz", _npz(11, quaternion_j2000=q, observed_at=outside))], plan_id=plan["id"])
    assert r.status_code == 422 and "none of the plan's access windows" in r.json()["detail"][0]["msg"]
    # the plan already labels tiangong-like frames (the test above): another target is refused
    ok = _post(client, [("p.npz", _npz(12, angles_deg=(1.0, 1.0, 1.0)))], plan_id=plan["id"])
    assert ok.status_code == 201
    other = client.post(
        "/v1/targets/comsat-like/labelled-frames",
        files=[("files", ("c.npz", _npz(13, angles_deg=(0.0, 0.0, 0.0))))],
        data={"plan_id": plan["id"]},
        headers=A,
    )
    assert other.status_code == 422 and "images one target" in other.json()["detail"][0]["msg"]
    unknown = client.get("/v1/targets/no-such-target/labelled-frames", headers=A)
    assert unknown.status_code == 422 and "unknown target" in unknown.json()["detail"][0]["msg"]


def test_a_file_stored_meanwhile_by_another_request_is_a_conflict_not_a_500(client):
    """Two uploads of one file at once both pass the 'already stored' check; the second commit is refused."""
    from app import crud
    from app.db.models import LabelledFrame
    from app.errors import Conflict

    def row(owner):
        return LabelledFrame(
            operator_id=owner,
            target=T,
            scene="race",
            input_name="r.npz",
            input_sha256="f" * 64,
            angles_deg=[0.0, 0.0, 0.0],
            frame_sha256="0" * 64,
        )

    with client.app.state.session_factory() as session:
        owner = session.scalar(select(LabelledFrame.operator_id).limit(1))
        crud.create_labelled(session=session, rows=[row(owner)])
        with pytest.raises(Conflict, match="meanwhile"):
            crud.create_labelled(session=session, rows=[row(owner)])
        assert len(crud.labelled_inputs(session=session, operator_id=owner, target=T, digests=["f" * 64])) == 1


def _frame_shas(settings, names):
    engine = create_engine(settings.database_url)
    with engine.connect() as conn:
        rows = conn.execute(
            select(LabelledFrame.input_name, LabelledFrame.frame_sha256).where(LabelledFrame.input_name.in_(names))
        ).all()
    engine.dispose()
    return dict(rows)


def test_png_and_npy_frames_take_their_labels_from_the_form(client, settings):
    """An image file's label is a form field, one per image file in order (an .npz among them keeps its own): the
    frame stored is the one the same image gives as an .npz written by inference.labelled.write_frame."""
    from PIL import Image

    rng = np.random.default_rng(21)
    png_pixels = (rng.random((64, 64)) * 200 + 20).astype(np.uint8)
    png = io.BytesIO()
    Image.fromarray(png_pixels, mode="L").save(png, format="PNG")
    npy_pixels = rng.random((64, 64)) + 0.01
    npy = io.BytesIO()
    np.save(npy, npy_pixels)
    files = [
        ("f.png", png.getvalue()),
        ("own.npz", _npz(22, angles_deg=(5.0, 5.0, 5.0))),
        ("f.npy", npy.getvalue()),
    ]
    r = _post(client, files, angles_deg=["10,-20,30", "-1.5, 2, 170"], scene="images")
    assert r.status_code == 201, r.text
    stored = {f["name"]: f["angles_deg"] for f in r.json()["stored"]}
    assert stored == {"f.png": [10.0, -20.0, 30.0], "own.npz": [5.0, 5.0, 5.0], "f.npy": [-1.5, 2.0, 170.0]}
    # the same images as .npz files written by the folder format's own writer store the same frames
    ref = io.BytesIO()
    write_frame(ref, png_pixels.astype(np.float64), angles_deg=(0.0, 1.0, 2.0))
    ref_npy = io.BytesIO()
    write_frame(ref_npy, npy_pixels, angles_deg=(0.0, 1.0, 3.0))
    assert _post(client, [("ref.npz", ref.getvalue()), ("ref-npy.npz", ref_npy.getvalue())]).status_code == 201
    shas = _frame_shas(settings, ["f.png", "ref.npz", "f.npy", "ref-npy.npz"])
    assert shas["f.png"] == shas["ref.npz"] and shas["f.npy"] == shas["ref-npy.npz"]
    # the same image and label again: already stored; under another label: another frame
    again = _post(client, [("f.png", png.getvalue())], angles_deg="10,-20,30").json()
    assert again["already_stored"] == ["f.png"]
    other = _post(client, [("f.png", png.getvalue())], angles_deg="11,-20,30").json()
    assert [f["angles_deg"] for f in other["stored"]] == [[11.0, -20.0, 30.0]]


@pytest.mark.parametrize(
    ("form", "field", "says"),
    [
        ({}, "angles_deg", "need one angles_deg each"),
        ({"angles_deg": ["1,2,3", "4,5,6"]}, "angles_deg", "got 2"),
        ({"angles_deg": "1,2"}, "angles_deg", "3 finite numbers"),
        ({"angles_deg": "0,95,0"}, "angles_deg", "y within"),
        ({"angles_deg": "1,2,3", "quaternion_j2000": "1,0,0,0"}, "angles_deg", "not both"),
        ({"quaternion_j2000": "1,0,0,0"}, "observed_at", "observed_at"),
    ],
)
def test_an_image_file_s_bad_form_label_is_refused_and_nothing_is_stored(client, settings, form, field, says):
    before = _count(settings)
    npy = io.BytesIO()
    np.save(npy, np.random.default_rng(31).random((64, 64)) + 0.01)
    r = _post(client, [("good.npz", _npz(98, angles_deg=(0.0, 0.0, 0.0))), ("x.npy", npy.getvalue())], **form)
    assert r.status_code == 422, r.text
    detail = r.json()["detail"][0]
    assert field in [str(v) for v in detail["loc"]] and says in detail["msg"], detail
    assert _count(settings) == before
