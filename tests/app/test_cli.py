import json
import re
import subprocess
import sys

import pytest

from app.schemas import CAMPAIGN_EXAMPLE, PAPER_EXAMPLE


def _gsa(*args, cwd, env_extra=None):
    import os

    env = dict(os.environ, GSA_DATA_DIR=str(cwd / "data"))
    env.update(env_extra or {})
    return subprocess.run([sys.executable, "-m", "app.cli", *args], capture_output=True, text=True, cwd=cwd, env=env)


def _on_a_terminal(args, cwd):
    """Run gsa with its stderr on a pseudo-terminal; return what it wrote there."""
    import os
    import pty

    master, slave = pty.openpty()
    env = dict(os.environ, GSA_DATA_DIR=str(cwd / "data"))
    proc = subprocess.run(
        [sys.executable, "-m", "app.cli", *args], stdout=subprocess.DEVNULL, stderr=slave, cwd=cwd, env=env
    )
    os.close(slave)
    chunks = []
    while True:
        try:
            chunk = os.read(master, 65536)
        except OSError:
            break
        if not chunk:
            break
        chunks.append(chunk)
    os.close(master)
    assert proc.returncode == 0
    return b"".join(chunks).decode(errors="replace")


def test_plan_prints_table_json_and_plot(tmp_path):
    req = tmp_path / "paper.json"
    req.write_text(json.dumps(PAPER_EXAMPLE))
    out = _gsa("plan", str(req), "--plot", str(tmp_path / "plan.png"), cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    assert "candidates" in out.stdout and "verification (numerical J2)" in out.stdout
    assert (tmp_path / "plan.png").stat().st_size > 10_000
    js = _gsa("plan", str(req), "--json", cwd=tmp_path)
    assert json.loads(js.stdout)["phasing"]["verification"]["miss_km"] < 1e-3


def test_bad_request_is_one_line_and_nonzero(tmp_path):
    bad = dict(PAPER_EXAMPLE, ground_station={"name": "GS", "latitude_deg": 95, "longitude_deg": 0})
    req = tmp_path / "bad.json"
    req.write_text(json.dumps(bad))
    out = _gsa("plan", str(req), cwd=tmp_path)
    assert out.returncode == 2
    assert out.stderr.count("\n") == 1 and "latitude_deg" in out.stderr
    missing = _gsa("plan", str(tmp_path / "nope.json"), cwd=tmp_path)
    assert missing.returncode == 2 and "cannot read" in missing.stderr
    int8 = _gsa("export", "--run", str(tmp_path / "run"), "--int8", "--out", str(tmp_path / "m"), cwd=tmp_path)
    assert int8.returncode == 2 and int8.stderr.count("\n") == 1 and "--int8 needs --frames DATA" in int8.stderr


def test_keys_create_list_revoke(tmp_path):
    assert _gsa("db", "upgrade", cwd=tmp_path).returncode == 0
    made = _gsa("keys", "create", "alice", cwd=tmp_path)
    assert made.returncode == 0
    key_id, key = made.stdout.split()
    assert key.startswith("gsa_")
    listed = _gsa("keys", "list", cwd=tmp_path).stdout
    assert key_id in listed and "active" in listed and key not in listed
    assert "role=operator" in listed  # a key's role is the operator's own objects unless made admin
    assert _gsa("keys", "role", key_id, "admin", cwd=tmp_path).returncode == 0
    assert any(key_id in ln and "role=admin" in ln for ln in _gsa("keys", "list", cwd=tmp_path).stdout.splitlines())
    admin_id = _gsa("keys", "create", "root", "--admin", cwd=tmp_path).stdout.split()[0]
    assert any(admin_id in ln and "role=admin" in ln for ln in _gsa("keys", "list", cwd=tmp_path).stdout.splitlines())
    bad_role = _gsa("keys", "role", key_id, "owner", cwd=tmp_path)
    assert bad_role.returncode == 2 and "owner" in bad_role.stderr
    assert _gsa("keys", "role", "no-such-id", "admin", cwd=tmp_path).returncode == 2
    assert _gsa("keys", "revoke", key_id, cwd=tmp_path).returncode == 0
    assert "revoked" in _gsa("keys", "list", cwd=tmp_path).stdout
    assert _gsa("keys", "revoke", "no-such-id", cwd=tmp_path).returncode == 2


def test_estimate_locally_with_plot(tmp_path, smoke_models):
    import io

    import numpy as np

    from inference.simulation.radar import Imager
    from inference.simulation.scene import simulate
    from inference.simulation.targets import tiangong_like
    from tests.utils.models import SMOKE_RADAR

    frame = simulate(tiangong_like(), Imager(SMOKE_RADAR), (5.0, 5.0, 5.0), 10.0, 0).image
    buf = io.BytesIO()
    np.save(buf, frame)
    (tmp_path / "f.npy").write_bytes(buf.getvalue())
    out = _gsa(
        "estimate",
        str(tmp_path / "f.npy"),
        "--models",
        str(smoke_models),
        "--plot",
        str(tmp_path / "e.png"),
        cwd=tmp_path,
    )
    assert out.returncode == 0, out.stderr
    assert "quaternion" in out.stdout and (tmp_path / "e.png").stat().st_size > 5000
    np.save(tmp_path / "bad.npy", np.zeros((3, 3, 3)))
    bad = _gsa("estimate", str(tmp_path / "bad.npy"), "--models", str(smoke_models), cwd=tmp_path)
    assert bad.returncode == 2 and "2-D" in bad.stderr and bad.stderr.count("\n") == 1
    # --normalised takes a data set's (already normalised) frame as sent, and refuses one that is not.
    from inference.frames import normalise_frame

    np.save(tmp_path / "n.npy", normalise_frame(np.abs(frame)))
    ok = _gsa("estimate", str(tmp_path / "n.npy"), "--normalised", "--models", str(smoke_models), cwd=tmp_path)
    assert ok.returncode == 0 and "quaternion" in ok.stdout, ok.stderr
    assert "hint" not in ok.stdout
    twice = _gsa("estimate", str(tmp_path / "n.npy"), "--models", str(smoke_models), cwd=tmp_path)
    assert twice.returncode == 0
    if "NOT TRUSTED" in twice.stdout:  # an untrusted answer to a frame already normalised says what to add
        assert "add --normalised" in twice.stdout
    np.save(tmp_path / "raw.npy", np.abs(frame))
    raw = _gsa("estimate", str(tmp_path / "raw.npy"), "--normalised", "--models", str(smoke_models), cwd=tmp_path)
    assert raw.returncode == 2 and "values in [0, 1]" in raw.stderr and raw.stderr.count("\n") == 1


def test_estimate_options_that_need_each_other_are_one_line_errors(tmp_path):
    (tmp_path / "f.npy").write_bytes(b"unused")
    cases = [
        (["--plan-id", "p"], "need --server"),
        (["--server", "http://127.0.0.1:9", "--plan-id", "p"], "together"),
        (["--range-cell-m", "0.1"], "together"),
        (["--range-cell-m", "0", "--cross-range-cell-m", "0.1"], "over 0"),
    ]
    for extra, says in cases:
        out = _gsa("estimate", str(tmp_path / "f.npy"), *extra, cwd=tmp_path)
        assert out.returncode == 2 and says in out.stderr and out.stderr.count("\n") == 1, (extra, out.stderr)


def test_simulate_a_pass_then_fuse_it(tmp_path, smoke_models):
    """gsa simulate --pass writes a pass the way a radar would form it; gsa pass fuses it (smoke models)."""
    req = tmp_path / "paper.json"
    req.write_text(json.dumps(PAPER_EXAMPLE))
    radar = ["--n-range", "64", "--n-azimuth", "64", "--bandwidth-hz", "0.4e9", "--aperture-deg", str(5.1 / 4)]
    out = _gsa("simulate", "--pass", str(req), "--out", str(tmp_path / "pass"), "--frames", "5", *radar, cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    rec = json.loads((tmp_path / "pass" / "pass.json").read_text())
    assert len(rec["frames"]) == 5 and (tmp_path / "pass" / "frames.png").stat().st_size > 5000
    f0 = rec["frames"][0]
    assert f0["observed_at"].endswith("Z") and f0["cross_range_cell_m"] > 0
    for key in ("attitude_observation", "attitude_lvlh", "attitude_j2000", "observation_axes_in_lvlh"):
        assert key in f0
    fused = _gsa(
        "pass", str(tmp_path / "pass"), "--models", str(smoke_models), "--plot", str(tmp_path / "p.png"), cwd=tmp_path
    )
    assert fused.returncode == 0, fused.stderr
    assert "fused, body to LVLH" in fused.stdout and (tmp_path / "p.png").stat().st_size > 10_000
    assert "fitted" not in fused.stderr  # no bar where stderr is not a terminal
    bar = _on_a_terminal(["pass", str(tmp_path / "pass"), "--models", str(smoke_models)], cwd=tmp_path)
    assert "5 frames estimated" in bar and "5/5 fitted" in bar and "] fused" in bar, bar
    as_json = _gsa("pass", str(tmp_path / "pass"), "--models", str(smoke_models), "--json", cwd=tmp_path)
    frames = json.loads(as_json.stdout)["frames"]
    assert len(frames) == 5 and "sweep" in fused.stdout
    # pass.json's integration times go in as the radar's measured sweeps: the aperture over each one's time
    for f, r in zip(frames, rec["frames"], strict=True):
        assert f["sweep_deg_s"] == pytest.approx(5.1 / 4 / r["integration_s"], rel=1e-3)
    rec["frames"][2]["integration_s"] = -1.0
    (tmp_path / "pass" / "pass.json").write_text(json.dumps(rec))
    bad = _gsa("pass", str(tmp_path / "pass"), "--models", str(smoke_models), cwd=tmp_path)
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1 and "integration_s" in bad.stderr, bad.stderr


def test_bad_pass_requests_are_one_line_errors(tmp_path, capsys, monkeypatch):
    """In this process (the command's own main; a child process per case cost 2 s of imports each)."""
    from app.cli import main

    monkeypatch.setenv("GSA_DATA_DIR", str(tmp_path / "data"))
    req = tmp_path / "paper.json"
    req.write_text(json.dumps(PAPER_EXAMPLE))
    cases = [
        (["--window", "999"], "window 999 does not exist"),
        (["--attitude-lvlh", "1,2"], "--attitude-lvlh"),
        (["--spin-deg-s", "50"], "spin_deg_s"),
        (["--snr-reference", "12"], "--snr-reference"),
    ]
    for extra, message in cases:
        capsys.readouterr()
        code = main(["simulate", "--pass", str(req), "--out", str(tmp_path / "p"), *extra])
        err = capsys.readouterr().err
        assert code == 2 and err.count("\n") == 1 and message in err, (extra, err)
        assert not (tmp_path / "p").exists() and not (tmp_path / "p.partial").exists()
    (tmp_path / "taken").mkdir()
    assert main(["simulate", "--pass", str(req), "--out", str(tmp_path / "taken")]) == 2
    assert "exists" in capsys.readouterr().err
    assert main(["pass", str(tmp_path / "taken")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "pass.json" in err


def test_plan_export_writes_every_format(tmp_path):
    req = tmp_path / "paper.json"
    req.write_text(json.dumps(PAPER_EXAMPLE))
    out = _gsa("plan", str(req), "--export", str(tmp_path / "x"), cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    names = sorted(p.name for p in (tmp_path / "x").iterdir())
    assert names == [
        "access.csv",
        "oem.txt",
        "oem.xml",
        "opm.txt",
        "opm.xml",
        "plan.czml",
        "plan.geojson",
        "pointing.csv",
    ]
    assert re.match(r"CCSDS_OPM_VERS\s*= 3.0\n", (tmp_path / "x" / "opm.txt").read_text())
    assert '<opm id="CCSDS_OPM_VERS" version="3.0">' in (tmp_path / "x" / "opm.xml").read_text()
    again = _gsa("plan", str(req), "--export", str(tmp_path / "x"), cwd=tmp_path)
    assert again.returncode == 2 and "not empty" in again.stderr and again.stderr.count("\n") == 1


def test_campaign_prints_its_scenes_plots_and_exports(tmp_path):
    """A week and a day from 2022-12-15: one scene (2022-12-22 23:31), its burn, the stretches."""
    req = tmp_path / "campaign.json"
    req.write_text(json.dumps({**CAMPAIGN_EXAMPLE, "duration_days": 8}))
    out = _gsa("campaign", str(req), "--plot", str(tmp_path / "c.png"), "--export", str(tmp_path / "x"), cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    assert "1 scene(s)" in out.stdout and "phasing" in out.stdout and "stretches searched" in out.stdout
    assert (tmp_path / "c.png").stat().st_size > 10_000
    names = sorted(p.name for p in (tmp_path / "x").iterdir())
    assert names == ["access.csv", "campaign.czml", "campaign.geojson", "oem.txt", "opm.txt", "pointing.csv"]
    assert (tmp_path / "x" / "opm.txt").read_text().count("MAN_EPOCH_IGNITION") == 1


@pytest.mark.parametrize(
    ("change", "field"),
    [({"duration_days": 91}, "duration_days"), ({"dv_budget_m_s": -5}, "dv_budget_m_s")],
)
def test_bad_campaign_is_one_line_and_nonzero(tmp_path, change, field):
    req = tmp_path / "bad.json"
    req.write_text(json.dumps({**CAMPAIGN_EXAMPLE, **change}))
    out = _gsa("campaign", str(req), cwd=tmp_path)
    assert out.returncode == 2 and out.stderr.count("\n") == 1 and field in out.stderr, out.stderr


def test_plan_without_a_request_and_a_misspelt_field_say_what_to_fix(tmp_path):
    none = _gsa("plan", cwd=tmp_path)
    assert none.returncode == 2 and "not both" not in none.stderr and "--example" in none.stderr
    body = json.loads(json.dumps(PAPER_EXAMPLE))
    body["target"]["elements"]["inclinaton_deg"] = 43
    req = tmp_path / "typo.json"
    req.write_text(json.dumps(body))
    out = _gsa("plan", str(req), cwd=tmp_path)
    assert out.returncode == 2 and out.stderr.count("\n") == 1
    assert "target.elements.inclinaton_deg: not a field this request takes: did you mean inclination_deg?" in out.stderr
    assert "function-after" not in out.stderr
    # Every error on the one line, each in the request's own words (no union member's class, no "Value error").
    body["ground_station"]["latitude_deg"] = 95
    body["serch"] = {"duration_days": 2}
    req.write_text(json.dumps(body))
    out = _gsa("plan", str(req), cwd=tmp_path)
    assert out.returncode == 2 and out.stderr.count("\n") == 1
    assert "ground_station.latitude_deg: Input should be less than or equal to 90" in out.stderr
    assert "serch: not a field this request takes: did you mean search?" in out.stderr
    assert "inclinaton_deg" in out.stderr and "StationIn" not in out.stderr, out.stderr


def test_simulate_a_scene_as_labelled_frames_and_place_j2000_labels_by_the_plan(tmp_path, smoke_models):
    """gsa simulate --scene writes the labelled-frame format; a folder labelled only in J2000 is placed by --plan."""
    import numpy as np

    from app.cli.labelled import read_with_plan
    from inference.labelled import read_folder
    from inference.rotations import geodesic_deg

    req = tmp_path / "paper.json"
    req.write_text(json.dumps(PAPER_EXAMPLE))
    radar = ["--n-range", "64", "--n-azimuth", "64", "--bandwidth-hz", "0.4e9", "--aperture-deg", str(5.1 / 4)]
    out = _gsa(
        "simulate",
        "--scene",
        str(req),
        "--out",
        str(tmp_path / "labelled"),
        "--frames",
        "6",
        "--physics",
        "po",
        "--roughness",
        "0.3",
        "--label-error-deg",
        "0.3",
        *radar,
        cwd=tmp_path,
    )
    assert out.returncode == 0, out.stderr
    assert "by physical optics" in out.stderr and "gsa adapt --frames" in out.stdout
    rec = json.loads((tmp_path / "labelled" / "scene.json").read_text())
    assert rec["physics"] == "po" and rec["label_error_deg"] == 0.3 and len(rec["frames"]) == 6
    lab = read_folder(tmp_path / "labelled", 64)
    assert len(set(lab.scenes)) == 1 and np.all(lab.sigma_deg == 0.3)
    truth = np.array([f["attitude_observation"]["euler_zyx_deg"] for f in rec["frames"]])
    assert 0.01 < np.median(geodesic_deg(lab.angles_deg, truth)) < 1.5  # the observer's error, as asked
    # The same frames labelled only in J2000 (as an observer's file would be): the plan places them.
    only_j2000 = tmp_path / "j2000"
    only_j2000.mkdir()
    for f in sorted((tmp_path / "labelled").glob("*.npz")):
        with np.load(f) as z:
            np.savez(only_j2000 / f.name, **{k: z[k] for k in z.files if k != "angles_deg"})
    placed = read_with_plan(str(only_j2000), str(req), 64, (0.375, 0.42))
    assert geodesic_deg(placed.angles_deg, lab.angles_deg).max() < 0.05
    no_plan = _gsa("adapt", "--frames", str(only_j2000), "--base", str(smoke_models), "--out", "o", cwd=tmp_path)
    assert no_plan.returncode == 2 and "--plan" in no_plan.stderr and no_plan.stderr.count("\n") == 1, no_plan.stderr
    one_scene = _gsa(
        "adapt",
        "--frames",
        str(only_j2000),
        "--plan",
        str(req),
        "--base",
        str(smoke_models),
        "--out",
        "o",
        cwd=tmp_path,
    )
    assert one_scene.returncode == 2 and "adapting needs at least 4, from 2 scenes" in one_scene.stderr, (
        one_scene.stderr
    )
    both = _gsa("simulate", "--scene", str(req), "--pass", str(req), "--out", "x", cwd=tmp_path)
    assert both.returncode == 2 and "not both" in both.stderr
    missing = _gsa("simulate", "--scene", "no-such-plan", "--out", "x", cwd=tmp_path)
    assert missing.returncode == 2 and "no such file" in missing.stderr and missing.stderr.count("\n") == 1, (
        missing.stderr
    )


def test_simulate_a_campaign_scene_from_this_machines_database(tmp_path):
    """gsa simulate --scene CAMPAIGN:K simulates the pass of the campaign's scene K (its T_access inside it); a scene
    number it does not have is one line."""
    from datetime import UTC, datetime, timedelta

    from sqlalchemy import create_engine

    from app.db.models import Operator
    from app.schemas import AccessCreate
    from app.services.planning import run_access
    from tests.utils.databases import store_campaign_row

    assert _gsa("db", "upgrade", cwd=tmp_path).returncode == 0
    windows = run_access(
        AccessCreate(target=PAPER_EXAMPLE["target"], ground_station=PAPER_EXAMPLE["ground_station"], duration_days=2)
    ).model_dump(mode="json")["access_windows"]
    w = windows[2]
    t_access = datetime.fromisoformat(w["culmination"])
    url = f"sqlite:///{tmp_path / 'data' / 'gsa.db'}"
    engine = create_engine(url)
    with engine.begin() as conn:
        conn.execute(Operator.__table__.insert().values(id="op-1", name="cli", created_at=datetime.now(UTC)))
    engine.dispose()
    store_campaign_row(
        url, campaign_id="camp-1", operator_id="op-1", windows=windows, scenes=[{"t_access": t_access.isoformat()}]
    )
    radar = ["--n-range", "64", "--n-azimuth", "64", "--bandwidth-hz", "0.4e9", "--aperture-deg", str(5.1 / 4)]
    out = _gsa("simulate", "--scene", "camp-1:0", "--out", "lab", "--frames", "4", *radar, cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    rec = json.loads((tmp_path / "lab" / "scene.json").read_text())
    assert rec["scene"].startswith("camp-1-scene-0")
    rise = datetime.fromisoformat(rec["window"]["rise"].replace("Z", "+00:00"))
    end = datetime.fromisoformat(rec["window"]["set"].replace("Z", "+00:00"))
    assert rise - timedelta(seconds=1) <= t_access <= end + timedelta(seconds=1)  # the scene's own pass
    bad = _gsa("simulate", "--scene", "camp-1:3", "--out", "x", cwd=tmp_path)
    assert bad.returncode == 2 and "scenes 0 to 0" in bad.stderr and bad.stderr.count("\n") == 1, bad.stderr


def test_settings_that_cannot_be_used_are_one_line_naming_them(tmp_path):
    short = _gsa("serve", cwd=tmp_path, env_extra={"GSA_API_KEYS": "short", "GSA_DATA_DIR": str(tmp_path)})
    assert short.returncode == 2 and short.stderr.count("\n") == 1, short.stderr
    assert "GSA_API_KEYS holds a key of 5 characters" in short.stderr
    page = _gsa("serve", cwd=tmp_path, env_extra={"GSA_MAX_PAGE_SIZE": "0", "GSA_DATA_DIR": str(tmp_path)})
    assert page.returncode == 2 and "GSA_MAX_PAGE_SIZE" in page.stderr and page.stderr.count("\n") == 1, page.stderr


def test_a_reader_that_goes_away_ends_the_command_quietly():
    """`gsa plan --example paper | head -1`: the rest of the report meets a closed pipe; gsa stops with exit 0 and
    no traceback, as Unix tools do."""
    import subprocess
    import sys

    proc = subprocess.Popen(
        [sys.executable, "-m", "app.cli", "plan", "--example", "paper"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    assert proc.stdout is not None and proc.stderr is not None
    first = proc.stdout.readline()
    proc.stdout.close()
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=120) == 0, err
    assert first.startswith(b"epoch ") and "Traceback" not in err and "BrokenPipeError" not in err
