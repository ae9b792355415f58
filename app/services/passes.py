"""A pass's frames to one attitude in the target's orbital frame: each frame fitted, placed in LVLH, then fused."""

from __future__ import annotations

import math
from datetime import datetime
from typing import Any

import numpy as np

from app.errors import InputError
from app.services.estimation import checked_json, frames_at, matrix_attitude_json
from inference.frames import rotation_matrix
from inference.fusion import PassFrame, angle_deg, fuse

MIRROR = np.diag([1.0, 1.0, -1.0])  # M R M: a frame's near-mirror, a reflection through its own image plane
NO_BOUND_DEG = 10.0  # a frame whose fit bounds nothing counts as this uncertain


def check_times(plan_result: dict[str, Any], observed_at: list[datetime]) -> None:
    """Every frame's time must fall inside one of the plan's access windows (422 naming observed_at)."""
    windows = [
        (datetime.fromisoformat(w["rise"]), datetime.fromisoformat(w["set"]))
        for w in plan_result.get("access_windows", [])
    ]
    for k, t in enumerate(observed_at):
        if not any(rise <= t <= end for rise, end in windows):
            raise InputError(
                ["observed_at", k],
                f"frame {k}'s time {t.isoformat()} is in none of the plan's access windows: the station cannot see "
                "the target then",
            )


def fuse_frames(
    *, plan_request: dict[str, Any], checks: list[Any], observed_at: list[datetime], names: list[str]
) -> dict[str, Any]:
    """Place each checked frame's answer and alternatives in LVLH (``frames_at``), fuse them, and describe the pass."""
    t0 = min(observed_at)
    pass_frames = []
    lvlh_axes = []
    for k, (c, t) in enumerate(zip(checks, observed_at, strict=True)):
        axes = frames_at(plan_request, t)
        obs_in_lvlh = axes["lvlh"].T @ axes["observation"]
        answer = rotation_matrix(*(float(a) for a in c.angles_deg))
        cands = [answer, MIRROR @ answer @ MIRROR]
        cands += [rotation_matrix(*a.angles_deg) for a in c.alternatives]
        finite = [b for b in c.quality.uncertainty_deg if math.isfinite(b)]
        bound = max(finite) if len(finite) == 3 else NO_BOUND_DEG
        pass_frames.append(
            PassFrame(np.array([obs_in_lvlh @ r for r in cands]), bound, (t - t0).total_seconds(), names[k])
        )
        lvlh_axes.append(axes["lvlh"])
    fused = fuse(pass_frames)
    mid = len(observed_at) // 2
    t_mid = observed_at[mid]
    j2000 = lvlh_axes[mid] @ fused.rotation
    frames_out = []
    for k, (pf, c) in enumerate(zip(pass_frames, checks, strict=True)):
        chosen = int(np.argmin([angle_deg(fused.rotation, r) for r in pf.candidates]))
        frames_out.append({
            "index": k,
            "name": names[k],
            "observed_at": observed_at[k],
            **checked_json(c),
            "attitude_lvlh": matrix_attitude_json(pf.candidates[chosen]),
            "branch": ["answer", "near-mirror", *[f"alternative {j}" for j in range(len(c.alternatives))]][chosen],
            "used": k in fused.used,
            "rejected_because": fused.rejected.get(k),
            "residual_deg": round(fused.residual_deg[k], 4),
        })  # fmt: skip
    speed = float(np.linalg.norm(fused.rate_deg_s))
    return {
        "frames": frames_out,
        "attitude_lvlh": matrix_attitude_json(fused.rotation),
        "attitude_j2000": {**matrix_attitude_json(j2000), "at": t_mid},
        "uncertainty_deg": [round(b, 4) for b in fused.uncertainty_deg],
        "used": len(fused.used),
        "rejected": len(fused.rejected),
        "stable": fused.stable,
        "rate_deg_s": [round(float(r), 5) for r in fused.rate_deg_s],
        "rate_sigma_deg_s": [round(float(r), 5) if math.isfinite(r) else None for r in fused.rate_sigma_deg_s],
        "stability": (
            "three-axis stable over the pass (no body rate beyond the frames' scatter)"
            if fused.stable
            else f"turning at about {speed:.3f} deg/s: the fused attitude is the pass's mean, not a fixed one"
        ),
    }
