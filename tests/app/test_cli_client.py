"""gsa's client commands (plans, estimates, stations, plan/estimate --server) against the service in-process,
reached through httpx as a real one is; GSA_SERVER and GSA_API_KEY stand in for the flags."""

import json

import httpx
import numpy as np
import pytest

from app.cli import main
from app.schemas import PAPER_EXAMPLE
from tests.conftest import KEY_A

SERVER = "http://gsa.test"


@pytest.fixture
def served(client, monkeypatch):
    def request(method, url, **kwargs):
        kwargs.pop("timeout", None)
        assert url.startswith(SERVER), url
        return client.request(method, url[len(SERVER) :], **kwargs)

    monkeypatch.setattr(httpx, "request", request)
    monkeypatch.setenv("GSA_SERVER", SERVER)
    monkeypatch.setenv("GSA_API_KEY", KEY_A)
    return client


def _run(capsys, *argv):
    rc = main(list(argv))
    out, err = capsys.readouterr()
    return rc, out, err


def test_stations_plans_and_estimates_through_the_command_line(served, capsys, tmp_path):
    site = {**PAPER_EXAMPLE["ground_station"], "name": "cli site", "mask": [[0, 2], [180, 6]]}
    (tmp_path / "site.json").write_text(json.dumps(site))
    assert _run(capsys, "stations", "add", str(tmp_path / "site.json"))[0] == 0
    rc, out, _ = _run(capsys, "stations", "list")
    assert rc == 0 and "cli site" in out and "mask points" in out
    # A plan that names the stored station, planned and stored by the service.
    (tmp_path / "req.json").write_text(json.dumps({**PAPER_EXAMPLE, "ground_station": "cli site"}))
    rc, out, _ = _run(capsys, "plan", str(tmp_path / "req.json"))
    assert rc == 0 and out.startswith("plan ") and "* " in out  # the chosen candidate is marked
    plan_id = out.split()[1]
    rc, out, _ = _run(capsys, "plans", "list")
    assert rc == 0 and plan_id in out and "cli site" in out
    rc, out, _ = _run(capsys, "plans", "show", plan_id, "--json")
    assert rc == 0 and json.loads(out)["station_name"] == "cli site"
    # An estimate sent with --server (from GSA_SERVER), then listed and shown.
    np.save(tmp_path / "f.npy", np.random.default_rng(3).random((64, 64)).astype(np.float32))
    rc, out, _ = _run(capsys, "estimate", str(tmp_path / "f.npy"))
    assert rc == 0 and out.startswith("estimate "), out
    est_id = out.split()[1].rstrip(":")
    rc, out, _ = _run(capsys, "estimates", "list")
    assert rc == 0 and est_id in out
    rc, out, _ = _run(capsys, "estimates", "show", est_id)
    assert rc == 0 and est_id in out and "deg" in out
    assert _run(capsys, "stations", "delete", "cli site")[0] == 0


def test_refusals_are_one_line_with_the_services_words(served, capsys, monkeypatch, tmp_path):
    rc, _, err = _run(capsys, "plans", "show", "no-such-plan")
    assert rc == 2 and err.strip() == "gsa: error: server answered 404: Plan not found"
    (tmp_path / "req.json").write_text(json.dumps({**PAPER_EXAMPLE, "ground_station": "nowhere"}))
    rc, _, err = _run(capsys, "plan", str(tmp_path / "req.json"))
    assert rc == 2 and "server answered 422: ground_station: no station named 'nowhere'" in err
    assert len(err.strip().splitlines()) == 1
    monkeypatch.delenv("GSA_SERVER")
    rc, _, err = _run(capsys, "plans", "list")
    assert rc == 2 and "give --server URL or set GSA_SERVER" in err
    monkeypatch.setenv("GSA_API_KEY", "wrong")
    rc, _, err = _run(capsys, "plans", "list", "--server", SERVER)
    assert rc == 2 and "server answered 401" in err


def test_plan_examples_run_as_shipped(capsys):
    rc, out, _ = _run(capsys, "plan", "--example", "paper")
    assert rc == 0 and "212 access windows" in out and "chosen: T_access" in out
    assert "feasible: yes" in out  # a newcomer's first plan ends in a feasible scene (the 10-day one does not)
    rc, _, err = _run(capsys, "plan")
    assert rc == 2 and "--example" in err


def test_campaigns_and_passes_through_the_command_line(served, capsys, tmp_path):
    from app.schemas import CAMPAIGN_EXAMPLE

    (tmp_path / "campaign.json").write_text(json.dumps({**CAMPAIGN_EXAMPLE, "duration_days": 8}))
    rc, out, err = _run(capsys, "campaign", str(tmp_path / "campaign.json"))
    assert rc == 0 and out.startswith("campaign ") and "1 scene(s)" in out, err
    # Through the service the campaign is a job, followed to its end with its progress (never silent for minutes).
    assert "queued as job" in err and "done" in err.splitlines()[-1] and "%" in err, err
    campaign_id = out.split()[1]
    rc, out, _ = _run(capsys, "campaigns", "list")
    assert rc == 0 and campaign_id in out and "first T_access" in out
    rc, out, _ = _run(capsys, "campaigns", "show", campaign_id)
    assert rc == 0 and "phasing" in out and "stretches searched" in out and "aim: RTN of the target" in out
    # An id as the lists and the console show it: its first 8 characters.
    rc, short, _ = _run(capsys, "campaigns", "show", campaign_id[:8])
    assert rc == 0 and short == out
    rc, _, err = _run(capsys, "campaigns", "show", "zzzzzzzz")
    assert rc == 2 and "404" in err and err.count("\n") == 1
    # Re-planned from its own start state (what orbit determination would give there): the same scene, re-aimed.
    from tests.utils.orbits import opm_kvn

    stored = served.get(f"/v1/campaigns/{campaign_id}", headers={"X-API-Key": KEY_A}).json()
    start = stored["observer_state"]
    opm = opm_kvn(start["r_km"], start["v_km_s"], epoch=stored["epoch"].rstrip("Z"))
    (tmp_path / "od.json").write_text(
        json.dumps({"observer": {"name": "Sat_Obs", "opm": opm}, "from": stored["epoch"]})
    )
    rc, out, err = _run(capsys, "campaign", "replan", campaign_id, str(tmp_path / "od.json"))
    assert rc == 0 and f"re-planned from {campaign_id}" in out and "(re-aimed)" in out, err
    rc, _, err = _run(capsys, "campaign", "replan", "no-such-campaign", str(tmp_path / "od.json"))
    assert rc == 2 and "404" in err and err.count("\n") == 1
    rc, out, _ = _run(capsys, "passes", "list", "--json")
    assert rc == 0 and "count" in json.loads(out)


def test_labelled_frames_through_the_command_line(served, capsys, tmp_path):
    from inference.labelled import write_frame

    folder = tmp_path / "lab"
    folder.mkdir()
    rng = np.random.default_rng(5)
    for k in range(5):
        write_frame(folder / f"f{k}.npz", rng.random((64, 64)) + 0.01, angles_deg=(k, -k, 2 * k), scene=f"s{k % 2}")
    rc, out, err = _run(capsys, "labelled", "add", str(folder), "--target", "tiangong-like", "--batch", "2")
    assert rc == 0 and "5 labelled frames stored, 0 already there" in out and "5/5 files sent" in err, (out, err)
    assert "in 2 scene(s): s0 (3), s1 (2)" in out
    rc, out, _ = _run(capsys, "labelled", "add", str(folder), "--target", "tiangong-like")
    assert rc == 0 and "0 labelled frames stored, 5 already there" in out
    rc, out, _ = _run(capsys, "labelled", "list", "--target", "tiangong-like", "--limit", "2")
    assert rc == 0 and "the newest 2 of 5 shown; --limit N shows more" in out  # a cut list says so
    rc, out, _ = _run(capsys, "labelled", "list", "--target", "tiangong-like", "--scene", "s1", "--json")
    assert rc == 0 and {f["name"] for f in json.loads(out)["data"]} == {"f1.npz", "f3.npz"}
    rc, _, err = _run(capsys, "labelled", "list", "--target", "no-such")
    assert rc == 2 and "unknown target" in err and err.count("\n") == 1
    rc, _, err = _run(capsys, "labelled", "add", str(tmp_path / "none"), "--target", "tiangong-like")
    assert rc == 2 and "not a folder" in err
    rc, _, err = _run(capsys, "labelled", "delete", "--target", "tiangong-like")
    assert rc == 2 and "--scene S" in err and err.count("\n") == 1
    rc, out, _ = _run(capsys, "labelled", "delete", "--target", "tiangong-like", "--scene", "s1")
    assert rc == 0 and "deleted 2 labelled frames" in out and "s0 (3)" in out and "s1" not in out.split("deleted")[1]


def test_jobs_through_the_command_line(served, capsys):
    """A data set queued on the service, followed by `gsa jobs wait` to its end, listed, shown; a finished job's
    cancel and an unknown id are one line each with the service's words."""
    radar = {"n_range": 64, "n_azimuth": 64, "bandwidth_hz": 0.4e9, "aperture_deg": 1.275}
    job = served.post("/v1/datasets", json={"n": 4, "shard_size": 2, "radar": radar}, headers={"X-API-Key": KEY_A})
    assert job.status_code == 202, job.text
    job_id = job.json()["id"]
    rc, out, err = _run(capsys, "jobs", "wait", job_id, "--every", "0.2", "--timeout", "120")
    assert rc == 0 and f"job {job_id} done" in out and "content_sha256" in out, (out, err)
    assert "100.0% 4/4 done" in err  # the progress line, to the end
    rc, out, _ = _run(capsys, "jobs", "list", "--kind", "dataset", "--state", "done")
    assert rc == 0 and job_id in out and "dataset" in out
    rc, out, _ = _run(capsys, "jobs", "show", job_id)
    assert rc == 0 and "state     done" in out and f"see       /v1/jobs/{job_id}" in out and "jobs: done" in out
    rc, _, err = _run(capsys, "jobs", "cancel", job_id)
    assert rc == 2 and err.count("\n") == 1 and "already done" in err and "gsa jobs delete" in err
    rc, out, _ = _run(capsys, "jobs", "delete", job_id)
    assert rc == 0 and "deleted" in out
    rc, _, err = _run(capsys, "jobs", "show", job_id)
    assert rc == 2 and "404" in err
    rc, _, err = _run(capsys, "jobs", "show", "no-such-job")
    assert rc == 2 and "404" in err
