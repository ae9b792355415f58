"""What every benchmark shares: the median of warm runs and the machine line."""

from __future__ import annotations

import json
import os
import platform
import statistics
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np


def median_time(fn, repeat: int = 5) -> float:
    fn()
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def interleaved_medians(fns: dict[str, Callable[[], object]], repeat: int = 9) -> dict[str, float]:
    """Time each function ``repeat`` times in turn (a, b, c, a, b, c, ...); return each one's median seconds.

    On a shared virtual machine the speed drifts by tens of percent over seconds; taking the
    rounds in turn lets the drift fall on every contender alike, so their ratio holds.
    """
    for fn in fns.values():
        fn()
    times: dict[str, list[float]] = {k: [] for k in fns}
    for _ in range(repeat):
        for k, fn in fns.items():
            t0 = time.perf_counter()
            fn()
            times[k].append(time.perf_counter() - t0)
    return {k: statistics.median(v) for k, v in times.items()}


def machine() -> str:
    cpu, isa = platform.processor() or "unknown CPU", ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
            elif line.startswith("flags") and not isa:
                # int8 kernels differ by it (inference/export.py: quantize_int8), so each figure names it
                flags = set(line.split(":", 1)[1].split())
                isa = " (AVX-512 VNNI)" if "avx512_vnni" in flags else " (AVX-VNNI)" if "avx_vnni" in flags else ""
                isa = isa or (" (AVX2, no VNNI)" if "avx2" in flags else "")
    except OSError:
        pass
    return f"{cpu}{isa}, {os.cpu_count()} cores, Python {platform.python_version()}, numpy {np.__version__}"


def branches(
    answers: np.ndarray, truth: np.ndarray, checks: list[Any], close_deg: float = 5.0
) -> dict[str, np.ndarray]:
    """Each checked answer against the near-mirror pair (issue 43), per frame:

    * ``err``: its angle from the truth; ``to_mirror``: from the truth's near-mirror (z, -y, -x);
    * ``wrong``: a wrong-branch answer, over ``close_deg`` from the truth and nearer its near-mirror;
    * ``on_mirror``: of those, read within ``close_deg`` of the truth's near-mirror (its own near-mirror, listed, then
      lies as near the truth: the mirror is an isometry);
    * ``listed``: some alternative within ``close_deg`` of the truth."""
    from inference.fit import mirror
    from inference.rotations import geodesic_deg

    err = geodesic_deg(answers, truth)
    to_mirror = geodesic_deg(answers, np.array([mirror(t) for t in truth]))
    wrong = (err > close_deg) & (to_mirror < err)
    listed = np.array(
        [
            any(geodesic_deg(np.array(a.angles_deg), t)[0] <= close_deg for a in c.alternatives)
            for c, t in zip(checks, truth, strict=True)
        ],
        bool,
    )
    return {
        "err": err,
        "to_mirror": to_mirror,
        "wrong": wrong,
        "on_mirror": wrong & (to_mirror <= close_deg),
        "listed": listed,
    }


def stored_results(results: Path, prefix: str, names: Any) -> dict[str, dict[str, Any]]:
    """Each name's stored points (``results/PREFIX-NAME.json``), for those that have a file."""
    return {
        name: json.loads((results / f"{prefix}-{name}.json").read_text())
        for name in names
        if (results / f"{prefix}-{name}.json").is_file()
    }
