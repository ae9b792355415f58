"""One job's worker process: ``python -m app.services.job_worker JOB_ID`` (the dispatcher starts it).

It runs the job's kind (``KINDS``: a function of a :class:`JobContext`) and writes what happens to the job's row:
stage, counts, progress and a log tail as it goes (at most every half second, and a heartbeat in ``updated_at``),
then ``done`` with the result, ``failed`` with the reason, or ``cancelled``. Cancelling is a flag on the row read
between steps (``ctx.check()``, every progress report), and SIGTERM, which stops the work at the next step.

A database that stops answering does not fail the job: progress the row cannot take is kept and written once it
answers again, the final state is written with retries for up to ``DB_RETRY_S``, and a job whose own work met the
outage is queued again (up to ``MAX_ATTEMPTS`` starts, then failed saying so).
"""

from __future__ import annotations

import importlib
import logging
import os
import signal
import sys
import time
import traceback
from collections.abc import Callable
from typing import Any

from sqlalchemy import update
from sqlalchemy.exc import DBAPIError

from app.db.models import Job, utcnow
from app.services.jobs import MAX_ATTEMPTS, host, settings_from_env
from inference.errors import Cancelled

# kind -> "module:function"; the function takes a JobContext and returns the job's result (a JSON object).
KINDS = {
    "adaptation": "app.services.model_versions:run_adaptation",
    "dataset": "app.services.datasets:run_dataset",
    "campaign": "app.services.campaigns:run_campaign_job",
    "reestimate": "app.services.reestimation:run_reestimation",
    "pass": "app.services.passes:run_pass_job",
}
WRITE_EVERY_S = 0.5
DB_RETRY_S = 600.0  # how long a worker keeps trying to write its job's final state through a database outage


class JobContext:
    """What a job's code sees: its row's params, the settings, and ways to report and to hear of a cancel."""

    def __init__(self, job: Job, settings: Any, session_factory: Any) -> None:
        self.id = job.id
        self.kind = job.kind
        self.operator_id = job.operator_id
        self.params: dict[str, Any] = dict(job.params)
        self.attempt = job.attempts
        self.settings = settings
        self.session_factory = session_factory
        self._log: list[str] = job.log.splitlines() if job.log else []
        self._pending: dict[str, Any] = {}
        self._last = 0.0
        self.stopping = False
        self.outage = False  # the last write found the database not answering

    def say(self, line: str) -> None:
        """Add a line to the job's log (kept: the last 80)."""
        self._log = [*self._log, line.rstrip()[:500]][-80:]
        self._pending["log"] = "\n".join(self._log)
        self._flush(False)

    def report(
        self, stage: str | None = None, done: int | None = None, total: int | None = None, progress: float | None = None
    ) -> None:
        """Say where the work stands (any of stage, counts, share done); stops here if the job was cancelled."""
        if stage is not None:
            self._pending["stage"] = stage[:300]
        if done is not None:
            self._pending["done"] = int(done)
        if total is not None:
            self._pending["total"] = int(total)
        if progress is None and done is not None and total:
            progress = done / total
        if progress is not None:
            self._pending["progress"] = round(min(max(float(progress), 0.0), 1.0), 4)
        self.check()

    def check(self) -> None:
        """Raise Cancelled if the job was cancelled (a SIGTERM, or the row's flag)."""
        self._flush(False)
        if self.stopping:
            raise Cancelled("cancelled")

    def _flush(self, force: bool) -> None:
        now = time.monotonic()
        if not force and now - self._last < WRITE_EVERY_S:
            return
        self._last = now
        try:
            with self.session_factory() as s:
                values = {**self._pending, "updated_at": utcnow()}
                s.execute(update(Job).where(Job.id == self.id, Job.state == "running").values(**values))
                s.commit()
                self._pending = {}
                job = s.get(Job, self.id)
                if job is None or job.cancel_requested or job.state != "running":
                    self.stopping = True
        except DBAPIError as exc:  # the database does not answer: the work goes on, the row catches up later
            if force:
                raise
            if not self.outage:
                print(f"jobs: the database does not answer ({type(exc).__name__}); going on", file=sys.stderr)
            self.outage = True
        else:
            self.outage = False

    def finish(self, **values: Any) -> None:
        """Write the job's final state, through a database outage of up to ``DB_RETRY_S`` (then raise)."""

        def write() -> None:
            self._flush(True)
            with self.session_factory() as s:
                now = utcnow()
                values.setdefault("finished_at", now)
                s.execute(update(Job).where(Job.id == self.id).values(**values, updated_at=now))
                s.commit()

        deadline, delay = time.monotonic() + DB_RETRY_S, 0.5
        while True:
            try:
                write()
                return
            except DBAPIError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(delay)
                delay = min(2 * delay, 15.0)


def kind_function(kind: str) -> Callable[[JobContext], dict[str, Any]]:
    module, _, name = KINDS[kind].partition(":")
    fn: Callable[[JobContext], dict[str, Any]] = getattr(importlib.import_module(module), name)
    return fn


def run(job_id: str) -> int:
    from app.core.db import make_engine, make_session_factory

    settings = settings_from_env()
    factory = make_session_factory(make_engine(settings.database_url))
    with factory() as s:  # write first: a read then a write in one SQLite transaction can meet another's commit
        mine = s.execute(
            update(Job)
            .where(Job.id == job_id, Job.state == "running")
            .values(runner=f"{host()}:{os.getpid()}", stage="started")
        )
        s.commit()
        job = s.get(Job, job_id)
        if not getattr(mine, "rowcount", 0) or job is None:
            state = "gone" if job is None else job.state
            print(f"jobs: job {job_id} is {state}, not running: nothing to do", file=sys.stderr, flush=True)
            return 0  # cancelled before it started: nothing to do
        ctx = JobContext(job, settings, factory)

    def stop(_signum: int, _frame: Any) -> None:
        # Deaf to SIGTERM from here on: a second one (two DELETEs, the dispatcher stopping) must not interrupt the
        # clean-up half-way, leaving a .partial version or a tenant's frames in a temporary folder.
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        ctx.stopping = True
        raise Cancelled("cancelled")

    signal.signal(signal.SIGTERM, stop)
    ctx.say(f"jobs: {job.kind} started on {host()} (pid {os.getpid()}, attempt {job.attempts})")
    try:
        result = kind_function(job.kind)(ctx)
    except Cancelled:
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        ctx.say("jobs: cancelled; what it made so far is removed")
        ctx.finish(state="cancelled", stage="cancelled")
        return 0
    except DBAPIError as exc:  # the database stopped answering under the work itself: queued again, not failed
        reason = f"the database did not answer ({type(exc).__name__})"
        if job.attempts < MAX_ATTEMPTS:
            ctx.say(f"jobs: {reason}; queued again (start {job.attempts} of {MAX_ATTEMPTS})")
            ctx.finish(state="queued", stage=f"queued again: {reason}", runner="", finished_at=None)
        else:
            ctx.say(f"jobs: {reason}, on its last start; failed")
            ctx.finish(state="failed", error=f"{reason} on each of its {job.attempts} starts"[:2000])
        return 0
    except ValueError as exc:  # bad input the request could not see (every domain error is a ValueError)
        ctx.say(f"jobs: failed: {exc}")
        ctx.finish(state="failed", error=str(exc)[:2000])
        return 0
    except Exception as exc:
        for line in traceback.format_exc().splitlines()[-12:]:
            ctx.say(line)
        ctx.finish(state="failed", error=f"{type(exc).__name__}: {exc}"[:2000])
        return 1
    ctx.say("jobs: done")
    ctx.finish(state="done", stage="done", progress=1.0, result=result)
    return 0


def main(argv: list[str] | None = None) -> int:
    import faulthandler

    faulthandler.enable()  # a crash of the interpreter itself leaves its stack in the job's log
    os.umask(0o077)  # however it was started: what the job writes is 0700 / 0600 (docs/operations.md's promise)
    argv = sys.argv[1:] if argv is None else argv
    logging.basicConfig(level=logging.WARNING)
    if len(argv) != 1:
        print("usage: python -m app.services.job_worker JOB_ID", file=sys.stderr)
        return 2
    return run(argv[0])


if __name__ == "__main__":
    sys.exit(main())
