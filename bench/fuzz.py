"""Fuzzing figures for BENCHMARKS.md from the report of `make fuzz` (tests/app/api/test_fuzz.py)."""

from __future__ import annotations

import json
import sys
from collections import defaultdict
from datetime import UTC, datetime
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import machine  # noqa: E402
from bench.sections import replace_section  # noqa: E402


def main(report: str) -> None:
    rep = json.loads(Path(report).read_text())
    by_op: dict[str, dict[int, int]] = defaultdict(dict)
    for row in rep["results"]:
        by_op[row["operation"]][row["status"]] = row["count"]
    total = sum(sum(v.values()) for v in by_op.values())
    errors5 = sum(n for v in by_op.values() for code, n in v.items() if code >= 500)
    modes = ", ".join(f"{n} {m}" for m, n in sorted(rep.get("modes", {}).items()))
    today = datetime.now(UTC).strftime("%Y-%m-%d")
    lines = [
        "## Fuzzing",
        "",
        f"Machine: {machine()}. Date: {today}. Command: `make fuzz` (schemathesis from the app's OpenAPI schema,",
        f"{rep['examples_per_route']} generated requests per route on each of SQLite and PostgreSQL; {modes}).",
        f"{total} requests, {errors5} server errors; every response passed the status-code, content-type,",
        "header and body-schema checks, every schema-violating request was refused, and every schema-valid one",
        "was accepted or refused only by a rule a schema cannot state (positive-data acceptance with those told",
        "apart: a cross-field or physical rule, error type value_error; tests/app/api/test_fuzz.py).",
        "",
        "| route | responses by status |",
        "|---|---|",
    ]
    for op, codes in sorted(by_op.items()):
        lines.append(f"| {op} | " + ", ".join(f"{c}: {n}" for c, n in sorted(codes.items())) + " |")
    lines.append("")
    replace_section("Fuzzing", lines)
    print("\n".join(lines))


if __name__ == "__main__":
    main(sys.argv[1])
