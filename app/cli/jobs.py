"""``gsa jobs list|show|cancel|delete|wait``: your long work on the service (``/v1/jobs``)."""

from __future__ import annotations

import argparse
import json
import sys
import time
from typing import Any
from urllib.parse import quote

from app.cli.common import CliError, call_server, print_listing, resolve_id, utc_text

FINAL = ("done", "failed", "cancelled")


def _line(job: dict[str, Any]) -> str:
    """One line of where a job stands: a bar, the share, the counts, the stage, the time left."""
    width = 24
    filled = int(round(job["progress"] * width))
    counts = f" {job['done']}/{job['total']}" if job["total"] else ""
    eta = f", {job['eta_s']:.0f} s left" if job.get("eta_s") is not None else ""
    return f"[{'#' * filled}{'.' * (width - filled)}] {100 * job['progress']:5.1f}%{counts} {job['state']}: {job['stage']}{eta}"


def _show(job: dict[str, Any]) -> None:
    print(f"job {job['id']} ({job['kind']}, on {job['engine']}, attempt {job['attempts']})")
    print(f"  state     {job['state']}{' (cancel asked)' if job['cancel_requested'] else ''}")
    print(f"  progress  {_line(job)}")
    print(f"  created   {utc_text(job['created_at'])}   started {utc_text(job['started_at'])}")
    print(f"  finished  {utc_text(job['finished_at'])}")
    if job.get("result") is not None:
        print(f"  result    {json.dumps(job['result'])}")
    if job.get("result_url"):
        print(f"  see       {job['result_url']}")
    if job.get("error"):
        print(f"  error     {job['error']}")
    if job.get("log_tail"):
        print("  log (last lines):")
        for ln in job["log_tail"].splitlines()[-10:]:
            print(f"    {ln}")


def cmd_jobs(args: argparse.Namespace) -> int:
    """gsa jobs list|show|cancel|wait."""
    sub = args.jobs_cmd
    if sub == "list":

        def row(j: dict[str, Any]) -> str:
            return (
                f"{j['id']:<36}  {j['kind']:<10} {j['state']:<9} {100 * j['progress']:5.1f}%  "
                f"{utc_text(j['created_at']):<24}  {j['stage'][:50]}"
            )

        header = f"{'id':<36}  {'kind':<10} {'state':<9} {'done':>6}  {'created (UTC)':<24}  stage"
        filters = {"kind": args.kind, "state": args.state}
        return print_listing(args, "/v1/jobs", filters, "{count} jobs; newest {shown}:", header, row)
    path = f"/v1/jobs/{quote(resolve_id(args, '/v1/jobs', args.id, 'jobs'), safe='')}"
    if sub == "show":
        job = call_server(args, "GET", path).json()
        print(json.dumps(job, indent=2)) if args.json else _show(job)
        return 0
    if sub in ("cancel", "delete"):
        state = call_server(args, "GET", path).json()["state"]
        if sub == "cancel" and state in FINAL:
            raise CliError(f"job {args.id} is already {state}: nothing to cancel (gsa jobs delete removes it)")
        if sub == "delete":
            if state not in FINAL:
                raise CliError(f"job {args.id} is {state}: cancel it first (gsa jobs cancel {args.id})")
            call_server(args, "DELETE", path)
            print(f"job {args.id}: deleted, with its files")
            return 0
        job = call_server(args, "DELETE", path).json()
        said = "cancelled" if job["state"] == "cancelled" else "asked to stop (it says cancelled once it has)"
        print(f"job {job['id']}: {said}")
        return 0
    return _wait(args, path)


def follow(args: argparse.Namespace, path: str, timeout_s: float | None = None, every_s: float = 1.0) -> dict[str, Any]:
    """Follow a job to its end with a progress line on stderr (rewritten on a terminal; a line a stage otherwise);
    the job as it ended. CliError after ``timeout_s`` (the job goes on)."""
    tty = sys.stderr.isatty()
    deadline = time.monotonic() + timeout_s if timeout_s else None
    last = ""
    while True:
        job = call_server(args, "GET", path).json()
        text = _line(job)
        if tty:
            print(f"\r{text[:150]:<150}", end="", file=sys.stderr, flush=True)
        elif text != last and (job["stage"] != last.partition(": ")[2].split(",")[0] or job["state"] in FINAL):
            print(text, file=sys.stderr, flush=True)
        last = text
        if job["state"] in FINAL:
            break
        if deadline is not None and time.monotonic() > deadline:
            if tty:
                print(file=sys.stderr)
            raise CliError(f"job {job['id']} is still {job['state']} after {timeout_s:g} s (it goes on; wait again)")
        time.sleep(every_s)
    if tty:
        print(file=sys.stderr)
    return job


def submit(args: argparse.Namespace, path: str, **kw: Any) -> dict[str, Any]:
    """POST long work with ``Prefer: respond-async`` and follow its job (``follow``: the CLI never goes silent); the
    stored result (its ``result_url``) once done. A service that answers at once is taken at its word; a job that
    fails or is cancelled is one CliError line (``gsa jobs show ID`` has its log)."""
    r = call_server(args, "POST", path, headers={"Prefer": "respond-async"}, **kw)
    if r.status_code != 202:
        return dict(r.json())
    job = r.json()
    print(f"queued as job {job['id']}", file=sys.stderr, flush=True)
    done = follow(args, f"/v1/jobs/{quote(job['id'], safe='')}")
    if done["state"] != "done" or not done.get("result_url"):
        raise CliError(
            f"job {done['id']} {done['state']}"
            + (f": {done['error']}" if done.get("error") else "")
            + f" (gsa jobs show {done['id']} has its log)"
        )
    return dict(call_server(args, "GET", done["result_url"]).json())


def _wait(args: argparse.Namespace, path: str) -> int:
    """Follow a job to its end with a progress line; 0 when done, 1 when it failed or was cancelled."""
    job = follow(args, path, args.timeout, args.every)
    if args.json:
        print(json.dumps(job, indent=2))
    elif job["state"] == "done":
        print(f"job {job['id']} done" + (f": {job['result_url']}" if job.get("result_url") else ""))
        if job.get("result") is not None:
            print(json.dumps(job["result"]))
    else:
        print(f"job {job['id']} {job['state']}" + (f": {job['error']}" if job.get("error") else ""))
    return 0 if job["state"] == "done" else 1
