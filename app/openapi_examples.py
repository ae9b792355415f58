"""Real response examples for the API docs: what the service answers to the shipped example requests.

``python -m app.openapi_examples`` runs a fresh service (a temporary SQLite database, the shipped
models) in-process, sends the paper's plan (examples/paper-plan.json), its three-week campaign
(``CAMPAIGN_EXAMPLE``), the ISS access request
(examples/iss-access.json), the sample frame (examples/sample-frame.npy) and a station, and writes
each answer into app/response_examples/, long lists cut to a few entries (the docs say so). tests/app/api/test_examples.py
regenerates them and fails when the stored ones no longer match the service.
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path
from typing import Any

from app.api.examples import HERE, load

REPO = HERE.parents[1]
NAMES = ("plan", "campaign", "access", "estimate", "station")
KEY = "docs-example-key"
# What changes from run to run and is not compared: ids, times of creation, timings, links with ids.
VOLATILE = ("id", "created_at", "timings_s", "links", "request_id")


def _trim(body: dict[str, Any]) -> dict[str, Any]:
    out = dict(body)
    if "access_windows" in out:
        out["access_windows"] = out["access_windows"][:3]
    if "scenes" in out:  # a campaign: each scene's candidate without its long family of height changes
        out["scenes"] = [
            {**sc, "candidate": {**sc["candidate"], "family": sc["candidate"]["family"][:3]}} for sc in out["scenes"]
        ]
    if "candidates" in out:
        chosen = (out.get("chosen") or {}).get("t_access")
        keep = [c for k, c in enumerate(out["candidates"]) if k < 2 or c["t_access"] == chosen]
        out["candidates"] = keep
    return out


def generate() -> dict[str, dict[str, Any]]:
    """Send the example requests to a fresh in-process service; return its trimmed answers by name."""
    from fastapi.testclient import TestClient

    from app.core.config import Settings
    from app.core.db import upgrade_database
    from app.main import create_app
    from app.schemas import CAMPAIGN_EXAMPLE, PAPER_EXAMPLE, STATION_EXAMPLE

    with tempfile.TemporaryDirectory() as tmp:
        settings = Settings(data_dir=Path(tmp), api_keys=KEY, ort_threads=1)
        upgrade_database(settings.database_url)
        headers = {"X-API-Key": KEY}
        with TestClient(create_app(settings)) as client:
            plan = client.post("/v1/plans", json=PAPER_EXAMPLE, headers=headers)
            campaign = client.post("/v1/campaigns", json=CAMPAIGN_EXAMPLE, headers=headers)
            access = client.post(
                "/v1/access-windows", json=json.loads((REPO / "examples/iss-access.json").read_text()), headers=headers
            )
            frame = (REPO / "examples/sample-frame.npy").read_bytes()
            estimate = client.post(
                "/v1/estimates",
                files={"file": ("sample-frame.npy", frame)},
                data={"normalised": "true"},
                headers=headers,
            )
            station = client.post("/v1/stations", json=STATION_EXAMPLE, headers=headers)
        answers = {"plan": plan, "campaign": campaign, "access": access, "estimate": estimate, "station": station}
        for name, r in answers.items():
            if r.status_code >= 300:
                raise RuntimeError(f"the {name} example answered {r.status_code}: {r.text[:300]}")
        return {name: _trim(r.json()) for name, r in answers.items()}


def comparable(body: Any) -> Any:
    """The example without what changes from run to run."""
    if isinstance(body, dict):
        return {k: comparable(v) for k, v in body.items() if k not in VOLATILE}
    if isinstance(body, list):
        return [comparable(v) for v in body]
    return body


__all__ = ["HERE", "comparable", "generate", "load", "main"]


def main() -> int:
    for name, body in generate().items():
        (HERE / f"{name}.json").write_text(json.dumps(body, indent=1) + "\n")
        print(f"wrote {HERE / name}.json")
    return 0


if __name__ == "__main__":
    sys.exit(main())
