import json
import subprocess
import sys

from app.schemas import PAPER_EXAMPLE


def _gsa(*args, cwd, env_extra=None):
    import os

    env = dict(os.environ, GSA_DATA_DIR=str(cwd / "data"))
    env.update(env_extra or {})
    return subprocess.run([sys.executable, "-m", "app.cli", *args], capture_output=True, text=True, cwd=cwd, env=env)


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
    assert _gsa("keys", "revoke", key_id, cwd=tmp_path).returncode == 0
    assert "revoked" in _gsa("keys", "list", cwd=tmp_path).stdout
    assert _gsa("keys", "revoke", "no-such-id", cwd=tmp_path).returncode == 2


def test_estimate_locally_with_plot(tmp_path, smoke_models):
    import io

    import numpy as np

    from inference.isar import Imager, simulate
    from inference.targets import tiangong_like
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
    from inference.isar import normalise_frame

    np.save(tmp_path / "n.npy", normalise_frame(np.abs(frame)))
    ok = _gsa("estimate", str(tmp_path / "n.npy"), "--normalised", "--models", str(smoke_models), cwd=tmp_path)
    assert ok.returncode == 0 and "quaternion" in ok.stdout, ok.stderr
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
