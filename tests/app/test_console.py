"""The web console in a real headless Chromium (Debian's package) against a real `gsa serve`.

Every page loads with no failed request (the server's access log has no 4xx or 5xx, the page counts no
failed call), a plan and a campaign created through the API are in their lists, the plan's page draws its pass,
the campaign's lists its scenes and stretches; a screenshot
of each page is written to tests/screenshots/ for people to look at."""

from __future__ import annotations

import io
import json
import re
import shutil
import subprocess
import time
from datetime import datetime
from pathlib import Path

import httpx
import numpy as np
import pytest

from app.schemas import CAMPAIGN_EXAMPLE, PAPER_EXAMPLE
from inference.labelled import write_frame
from tests.conftest import KEY_A
from tests.utils.server import Server

ROOT = Path(__file__).resolve().parents[2]
SHOTS = ROOT / "tests" / "screenshots"
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--hide-scrollbars",
    "--virtual-time-budget=30000",
]


@pytest.fixture(scope="module")
def served(tmp_path_factory, smoke_models):
    data = tmp_path_factory.mktemp("console")
    env = {
        "GSA_DATA_DIR": str(data),
        "GSA_DATABASE_URL": f"sqlite:///{data}/gsa.db",
        "GSA_MODEL_DIR": str(smoke_models),
        "GSA_API_KEYS": KEY_A,
        "GSA_ORT_THREADS": "1",
        "GSA_LOG_LEVEL": "info",
    }
    srv = Server(env, workers=1, log_path=data / "server.log").start()
    headers = {"X-API-Key": KEY_A}
    plan = httpx.post(srv.url + "/v1/plans", json=PAPER_EXAMPLE, headers=headers, timeout=300).json()
    buf = io.BytesIO()
    np.save(buf, np.random.default_rng(2).random((64, 64)).astype(np.float32))
    est = httpx.post(
        srv.url + "/v1/estimates", files={"file": ("frame.npy", buf.getvalue())}, headers=headers, timeout=120
    ).json()
    campaign = httpx.post(srv.url + "/v1/campaigns", json=CAMPAIGN_EXAMPLE, headers=headers, timeout=300).json()
    w = plan["access_windows"][0]
    rise, end = datetime.fromisoformat(w["rise"]), datetime.fromisoformat(w["set"])
    stack = io.BytesIO()
    np.savez(stack, frames=np.random.default_rng(3).random((6, 64, 64)).astype(np.float32) + 0.05)
    times = [(rise + (end - rise) * (k + 1) / 7).isoformat() for k in range(6)]
    passed = httpx.post(
        srv.url + "/v1/passes",
        files={"files": ("pass.npz", stack.getvalue())},
        data={"plan_id": plan["id"], "observed_at": times},
        headers=headers,
        timeout=300,
    )
    assert passed.status_code == 201, passed.text
    labelled = []
    for k in range(6):  # two scenes' labelled frames, for the model sets page
        one = io.BytesIO()
        angles = (-30.0 + 10.0 * k, 5.0 * k - 10.0, 20.0 - 6.0 * k)
        write_frame(
            one, np.random.default_rng(10 + k).random((64, 64)) + 0.01, angles_deg=angles, scene=f"pass-{k % 2}"
        )
        labelled.append(("files", (f"lab{k}.npz", one.getvalue())))
    stored = httpx.post(
        srv.url + "/v1/targets/tiangong-like/labelled-frames", files=labelled, headers=headers, timeout=120
    )
    assert stored.status_code == 201, stored.text
    radar = {"n_range": 64, "n_azimuth": 64, "bandwidth_hz": 0.4e9, "aperture_deg": 1.275}
    job = httpx.post(srv.url + "/v1/datasets", json={"n": 4, "radar": radar}, headers=headers, timeout=60).json()
    for _ in range(600):  # finished before the pages are drawn (an active job's page looks again every 2 s)
        if httpx.get(f"{srv.url}/v1/jobs/{job['id']}", headers=headers).json()["state"] not in ("queued", "running"):
            break
        time.sleep(0.2)
    yield srv, plan, est, campaign, passed.json(), data / "server.log", job
    srv.stop()


def _browse(url: str, name: str, profile: Path) -> str:
    """The page's DOM after its scripts ran, and its screenshot in tests/screenshots/NAME.png."""
    assert CHROMIUM, "Debian's chromium is needed for the console tests: apt-get install chromium (make test does)"
    SHOTS.mkdir(exist_ok=True)
    base = [CHROMIUM, *FLAGS, f"--user-data-dir={profile}"]
    dom = subprocess.run([*base, "--dump-dom", url], capture_output=True, text=True, timeout=180).stdout
    subprocess.run(
        [*base, "--window-size=1280,1500", f"--screenshot={SHOTS / (name + '.png')}", url],
        capture_output=True,
        timeout=180,
    )
    return dom


def _status(dom: str) -> tuple[int, int]:
    m = re.search(r'id="status" data-failed="(\d+)" data-ready="(\d)"', dom)
    assert m, dom[-500:]
    return int(m.group(1)), int(m.group(2))


def test_console_pages_in_chromium(served, tmp_path):
    srv, plan, est, campaign, fused, log, job = served
    console = f"{srv.url}/console/#key={KEY_A}&"
    pages = {
        "plans": (f"{console}/plans", [plan["id"][:8], "Sat_Target"]),
        "plan": (
            f"{console}/plans/{plan['id']}",
            [
                'class="target_in_view"',
                'class="visibility_circle"',
                'class="night" d="M',
                '<svg id="sky"',
                'class="skytrack" d="M',
                'class="coast" d="M',
                "Not feasible",
                "Phasing burn",
                'id="candidates"',
                "stand-off (km)",
                "Radar at T_access",
                "radar el (deg)",
                "The fly-by in the target's orbital frame",
                '<svg class="panel encounter"',
                'class="flyby" d="M',
            ],
        ),
        "campaigns": (f"{console}/campaigns", [campaign["id"][:8], "first T_access"]),
        "campaign": (
            f"{console}/campaigns/{campaign['id']}",
            [
                'id="scenes"',
                'id="stretches"',
                "feasible scene(s)",
                "scene flown",
                "phasing",
                "aim within (km)",
                'id="flyscene"',
                '<svg class="panel encounter"',
                'id="dvchart"',
                'class="dvline"',
                "Delta-v against the budget",
                'data-export="pointing.csv?scene=',
                'data-export="geojson"',
            ],
        ),
        "estimates": (f"{console}/estimates", [est["id"][:8]]),
        "estimate": (
            f"{console}/estimates/{est['id']}",
            ['id="original" alt="original frame" hidden="" src="blob:', 'data-drawn="1"', "observation frame (fitted)"],
        ),
        "passes": (f"{console}/passes", [fused["id"][:8], "frames used"]),
        "pass": (
            f"{console}/passes/{fused['id']}",
            ['<svg class="panel"', 'class="framepoint"', 'id="passframes"', "Fused attitude, body to LVLH"],
        ),
        "jobs": (f"{console}/jobs", [job["id"][:8], 'id="jobs"', "<progress", ">done<", ">manifest</a>"]),
        "models": (
            f"{console}/models",
            [
                "Model sets",
                "version 0 answers you",
                "the shared default is 0",
                'class="labelpoint"',
                "6 in 2 scene(s)",
                "pass-1",
                "lab5.npz",
            ],
        ),
        "no-key": (f"{srv.url}/console/", ["Use this key"]),
        "wrong-key": (
            f"{srv.url}/console/#key=not-a-key-of-this-service&/plans",
            ["Use this key", 'id="refused"', "refused"],
        ),
    }
    for name, (url, expected) in pages.items():
        dom = _browse(url, name, tmp_path / name)
        failed, ready = _status(dom)
        assert failed == 0 and ready == 1, (name, dom[-1500:])
        for text in expected:
            assert text in dom, (name, text)
        assert (SHOTS / f"{name}.png").stat().st_size > 10_000, name
    # Every request the pages made (console files, API calls, images) answered below 400.
    lines = [json.loads(x) for x in log.read_text().splitlines() if x.startswith("{")]
    served_paths = [x for x in lines if "status" in x and "path" in x]
    assert any(x["path"].startswith("/console/") for x in served_paths)
    assert any(x["path"].endswith("/export/geojson") for x in served_paths)
    bad = [(x["path"], x["status"]) for x in served_paths if x["status"] >= 400]
    # the wrong-key page's own refusal (its DOM dump and its screenshot: two loads), and nothing else
    assert bad == [("/v1/plans", 401)] * 2, bad


def test_the_landing_page_links_the_console(client):
    assert 'href="/console/"' in client.get("/").text
    r = client.get("/console", follow_redirects=False)
    assert r.status_code in (307, 308) and r.headers["location"].endswith("/console/")


ISS = json.loads((ROOT / "examples" / "iss-plan.json").read_text())


def test_the_console_plans_from_a_pasted_tle_and_estimates_an_uploaded_frame(served, tmp_path):
    """An operator's first hour in the console, in a real Chromium: a mistyped TLE is refused with the server's
    message at the target's field and nothing is stored; the ISS's TLE pasted as it comes, an observer's elements
    and a new radar site give a plan whose page opens; a frame picked from disk gives an estimate whose page opens."""
    from tests.utils.browser import Browser

    srv, *_ = served
    headers = {"X-API-Key": KEY_A}
    plans_before = httpx.get(srv.url + "/v1/plans", headers=headers).json()["count"]
    browser = Browser(CHROMIUM, [f for f in FLAGS if not f.startswith("--virtual-time")], tmp_path / "profile")
    try:
        browser.goto(f"{srv.url}/console/#key={KEY_A}&/new-plan")
        browser.wait_for("document.getElementById('planform') !== null")

        def fill(name: str, value: str) -> None:
            browser.evaluate(
                f"document.getElementById('planform').elements.namedItem({json.dumps(name)}).value = "
                f"{json.dumps(value)}"
            )

        fill("target_name", "ISS (ZARYA)")
        fill("target_text", "1 25544U 98067A   08264.51782528 -.00002182  00000-0 -11606-4 0  2927\nnot a TLE line")
        fill("observer_name", "Observer")
        fill("observer_text", json.dumps(ISS["observer"]["elements"]))
        station = ISS["ground_station"]
        fill("gs_name", station["name"])
        fill("gs_lat", str(station["latitude_deg"]))
        fill("gs_lon", str(station["longitude_deg"]))
        fill("duration_days", "5")
        browser.evaluate("document.getElementById('plansubmit').click()")
        said = browser.wait_for(
            "[...document.querySelectorAll('fieldset[data-loc=\"target\"] .fielderror')].map(e => e.textContent)"
            ".join(' ')"
        )
        assert "line" in said.lower() or "tle" in said.lower(), said
        assert httpx.get(srv.url + "/v1/plans", headers=headers).json()["count"] == plans_before  # nothing stored
        fill("target_text", "\n".join(ISS["target"]["tle"]))  # as pasted from CelesTrak: a 3LE
        browser.evaluate("document.getElementById('plansubmit').click()")
        plan_id = browser.wait_for(
            "location.hash.startsWith('#/plans/') && document.getElementById('status').dataset.ready === '1' && "
            "document.body.innerText.includes('Radar at T_access') && location.hash.slice(8)",
            timeout_s=120,
        )
        stored = httpx.get(f"{srv.url}/v1/plans/{plan_id}", headers=headers).json()
        assert stored["target_name"] == "ISS (ZARYA)" and stored["station_name"] == station["name"]
        browser.screenshot(SHOTS / "new-plan-made.png")
        browser.goto(f"{srv.url}/console/#/new-plan")
        browser.wait_for("document.getElementById('planform') !== null")
        browser.evaluate("document.getElementById('paper').click()")
        browser.screenshot(SHOTS / "new-plan-form.png")

        browser.goto(f"{srv.url}/console/#/estimates")
        browser.wait_for("document.getElementById('estimateform') !== null")
        browser.set_files("#framefile", [ROOT / "examples" / "sample-frame.npy"])
        browser.evaluate("document.getElementById('estimatesubmit').click()")
        said = browser.wait_for("[...document.querySelectorAll('.fielderror')].map(e => e.textContent).join(' ')")
        assert "the models take 64x64" in said, said  # 256 x 256 for these small models: the server's words
        browser.evaluate("document.getElementById('estimateform').elements.namedItem('resample').checked = true")
        browser.evaluate("document.getElementById('estimatesubmit').click()")
        try:
            estimate_id = browser.wait_for(
                "location.hash.startsWith('#/estimates/') && document.getElementById('status').dataset.ready === '1' "
                "&& document.body.innerText.includes('observation frame') && location.hash.slice(12)",
                timeout_s=120,
            )
        except TimeoutError:
            raise AssertionError(
                browser.evaluate("location.hash + ' ' + document.body.innerText.slice(0, 800)")
            ) from None
        made = httpx.get(f"{srv.url}/v1/estimates/{estimate_id}", headers=headers).json()
        assert made["input_name"] == "sample-frame.npy"

        # A campaign from the paper's scene, 20 days.
        browser.goto(f"{srv.url}/console/#/new-campaign")
        browser.wait_for("document.getElementById('planform') !== null")
        browser.evaluate("document.getElementById('paper').click()")
        browser.evaluate("document.getElementById('planform').elements.namedItem('duration_days').value = '20'")
        browser.evaluate("document.getElementById('plansubmit').click()")
        campaign_id = browser.wait_for(
            "location.hash.startsWith('#/campaigns/') && document.getElementById('status').dataset.ready === '1' && "
            "document.getElementById('scenes') !== null && location.hash.slice(12)",
            timeout_s=180,
        )
        assert httpx.get(f"{srv.url}/v1/campaigns/{campaign_id}", headers=headers).status_code == 200

        # Labelled frames added on the model sets page; an adaptation the server refuses says why at its field.
        before = httpx.get(srv.url + "/v1/targets/tiangong-like/labelled-frames", headers=headers).json()["count"]
        frame = tmp_path / "lab-new.npz"
        write_frame(
            frame, np.random.default_rng(99).random((64, 64)) + 0.01, angles_deg=(1.0, 2.0, 3.0), scene="pass-9"
        )
        browser.goto(f"{srv.url}/console/#/models")
        browser.wait_for("document.querySelector('form.labelledform') !== null")
        browser.set_files("form.labelledform input[type=file]", [frame])
        browser.evaluate("document.querySelector('form.labelledform button').click()")
        browser.wait_for("document.body.innerText.includes('pass-9')")
        after = httpx.get(srv.url + "/v1/targets/tiangong-like/labelled-frames", headers=headers).json()["count"]
        assert after == before + 1
        browser.evaluate("document.querySelector('form.adaptform').elements.namedItem('max_minutes').value = '0'")
        browser.evaluate("document.querySelector('form.adaptform button').click()")
        said = browser.wait_for(
            "[...document.querySelectorAll('form.adaptform .fielderror')].map(e => e.textContent).join(' ')"
        )
        assert "0.1" in said, said  # max_minutes' lower bound, in the server's words
        browser.screenshot(SHOTS / "models-forms.png")
        assert browser.evaluate("document.getElementById('status').dataset.failed") == "0"
    finally:
        browser.close()
