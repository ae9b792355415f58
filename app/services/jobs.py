"""Jobs: long work (adaptations, data sets, campaigns on request) as rows, run by worker processes beside the server.

A request stores a ``queued`` row and answers 202 at once. A :class:`Dispatcher` thread in the server process
(started when there is work, gone when there is none) claims queued rows, at most ``GSA_JOB_WORKERS`` running on
this host at a time (a lock file under ``GSA_DATA_DIR`` makes the bound hold across the server's worker processes),
and runs each in its own child process (``python -m app.services.job_worker JOB_ID``), so the API stays responsive
while one trains, and a job that exhausts memory takes only itself down. The child writes its stage, counts,
progress and log to the row (``app.services.job_worker``); where ``GSA_RAY_ADDRESS`` is set, the work inside runs
on that Ray cluster.

Cancel (``DELETE``): a queued job is cancelled at once; a running one is asked to stop (a flag the worker reads
between steps, and SIGTERM where its process is on this host). A restart loses nothing: at start, a running job
whose process is gone is queued again (``resumed``; a data set keeps the shards it wrote) unless it was already
resumed twice; then it fails, saying why.
"""

from __future__ import annotations

import fcntl
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections import Counter
from collections.abc import Iterator
from contextlib import contextmanager
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from sqlalchemy import delete, func, select, update
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from app.core.config import Settings
from app.core.security import private_dir
from app.db.models import JOB_ACTIVE, JOB_FINAL, Job, new_id, utcnow
from app.errors import Conflict, TooMany

MAX_ATTEMPTS = 3  # a job is started at most this often (the first run and two resumptions after restarts)
POLL_S = 0.5
KINDS = ("adaptation", "dataset", "campaign", "reestimate", "pass")


def _count(result: Any) -> int:
    """Rows an UPDATE touched (``CursorResult.rowcount``; the generic Result type does not declare it)."""
    return int(getattr(result, "rowcount", 0))


def host() -> str:
    return socket.gethostname()


def pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except (OSError, ValueError):
        return False
    return True


def runner_pid(job: Job) -> int | None:
    """The pid of the process running ``job`` where that process is on this host."""
    name, _, pid = job.runner.rpartition(":")
    return int(pid) if name == host() and pid.isdigit() and int(pid) > 0 else None


def submit(
    session: Session,
    *,
    operator_id: str,
    kind: str,
    params: dict[str, Any],
    key: str | None = None,
    busy_message: str = "",
    total: int = 0,
    stage: str = "queued",
    engine: str = "local",
    job_id: str | None = None,
    cap: int | None = None,
) -> Job:
    """Store a queued job (its ``key`` must not be active already: else a 409 with ``busy_message``; the operator
    may have at most ``cap`` jobs queued or running, GSA_QUOTA_QUEUED_JOBS: else a 429 saying so)."""
    if kind not in KINDS:
        raise ValueError(kind)
    if cap is not None:
        active = session.scalar(
            select(func.count()).select_from(Job).where(Job.operator_id == operator_id, Job.state.in_(JOB_ACTIVE))
        )
        if int(active or 0) >= cap:
            raise TooMany(
                f"you have {active} jobs queued or running, the most one operator may (GSA_QUOTA_QUEUED_JOBS = {cap}); "
                "wait for one to end or cancel one (DELETE /v1/jobs/{id})"
            )
    job = Job(
        id=job_id or new_id(),
        operator_id=operator_id,
        kind=kind,
        key=key,
        state="queued",
        stage=stage,
        progress=0.0,
        done=0,
        total=total,
        created_at=utcnow(),
        params=params,
        log="",
        runner="",
        engine=engine,
        attempts=0,
        cancel_requested=False,
    )
    session.add(job)
    try:
        session.commit()
    except IntegrityError:
        session.rollback()
        raise Conflict(busy_message or f"a {kind} job for {key} is already queued or running") from None
    session.refresh(job)
    return job


def job_dir(settings: Settings, job_id: str) -> Path:
    """Where a job keeps what it needs beyond its row (a pass's frames) and its worker's output."""
    return Path(settings.data_dir) / "jobs" / job_id


def own(session: Session, operator_id: str, job_id: str) -> Job | None:
    job = session.get(Job, job_id)
    return job if job is not None and job.operator_id == operator_id else None


def listing(
    session: Session, operator_id: str, limit: int, offset: int, kind: str | None = None, state: str | None = None
) -> tuple[list[Job], int]:
    """The operator's jobs, newest first, filtered by kind and state; and how many match."""
    where = [Job.operator_id == operator_id]
    if kind:
        where.append(Job.kind == kind)
    if state:
        where.append(Job.state == state)
    total = int(session.scalar(select(func.count()).select_from(Job).where(*where)) or 0)
    rows = session.scalars(
        select(Job).where(*where).order_by(Job.created_at.desc(), Job.id).limit(limit).offset(offset)
    )
    return list(rows), total


def cancel(session: Session, job: Job, settings: Settings | None = None) -> Job:
    """Cancel ``job``: queued, at once, with what it keeps on disk (given ``settings``); running, stop its worker
    and what the worker started (it cleans up and says ``cancelled`` when it has). Idempotent while it runs."""
    if job.state in JOB_FINAL:
        raise Conflict(f"job {job.id} is already {job.state}; only a queued or running job can be cancelled")
    now = utcnow()
    gone = _count(
        session.execute(
            update(Job)
            .where(Job.id == job.id, Job.state == "queued")
            .values(state="cancelled", stage="cancelled before it started", finished_at=now, updated_at=now)
        )
    )
    if not gone:
        session.execute(update(Job).where(Job.id == job.id, Job.state == "running").values(cancel_requested=True))
    session.commit()
    session.refresh(job)
    if gone and settings is not None:
        import shutil

        shutil.rmtree(job_dir(settings, job.id), ignore_errors=True)
    pid = runner_pid(job)
    if job.state == "running" and pid is not None and pid != os.getpid():
        stop_group(pid, signal.SIGTERM)
    return job


def fair_order(queued: list[Job], running: Counter[str], last_start: dict[str, datetime] | None = None) -> list[Job]:
    """The queued jobs in the order they start: turn about between operators, so one operator's 300 jobs do not
    hold back another's one. A job's place is its operator's running jobs plus the jobs of that operator queued
    before it; at equal places the operator served longest ago (``last_start``: when its latest job started; never
    comes first) goes first, then the older job. ``queued`` comes oldest first."""
    never = datetime.min.replace(tzinfo=UTC)
    last = {op: (t if t.tzinfo else t.replace(tzinfo=UTC)) for op, t in (last_start or {}).items()}
    ahead: Counter[str] = Counter()
    places = []
    for k, job in enumerate(queued):
        places.append((running[job.operator_id] + ahead[job.operator_id], last.get(job.operator_id, never), k, job))
        ahead[job.operator_id] += 1
    return [job for *_, job in sorted(places, key=lambda p: (p[0], p[1], p[2]))]


def remove(session: Session, job: Job, settings: Settings) -> None:
    """Remove an ended job: its row, its folder and log, and a data set's files (the data set is the job's)."""
    import shutil

    if job.state not in JOB_FINAL:
        raise Conflict(f"job {job.id} is {job.state}; cancel it first (DELETE /v1/jobs/{job.id})")
    data = Path(settings.data_dir)
    session.execute(delete(Job).where(Job.id == job.id, Job.state.in_(JOB_FINAL)))
    session.commit()
    shutil.rmtree(job_dir(settings, job.id), ignore_errors=True)
    (data / "jobs" / f"{job.id}.log").unlink(missing_ok=True)
    if job.kind == "dataset":
        shutil.rmtree(data / "datasets" / job.id, ignore_errors=True)


def stop_group(pid: int, sig: int) -> None:
    """Signal a job's worker and every process it started (``gsa adapt``, simulation pools): the worker leads its
    own process group (the dispatcher starts it in a new session). A worker of another host, or one already gone,
    is left alone."""
    try:
        if os.getpgid(pid) == pid:
            os.killpg(pid, sig)
        else:
            os.kill(pid, sig)
    except OSError:
        pass


def append_log(log: str, lines: list[str], keep: int = 80) -> str:
    return "\n".join([*(log.splitlines() if log else []), *lines][-keep:])


def recover(session: Session, resume: bool = True) -> int:
    """Each running job of this host whose process is gone: at start (``resume``), queued again, or failed after
    MAX_ATTEMPTS starts, saying why; while serving, failed (its worker died: out of memory, killed). Return how
    many were touched. Another host's jobs are left to it."""
    touched = 0
    found = list(session.scalars(select(Job).where(Job.state == "running")))
    session.commit()  # each change below is a transaction of its own that writes first (SQLite: no stale read)
    for job in found:
        name, _, pid = job.runner.rpartition(":")
        if name != host() or not pid.isdigit():
            continue
        if int(pid) > 0 and int(pid) != os.getpid() and pid_alive(int(pid)):
            continue
        if not resume and int(pid) == 0:
            continue  # being started by a dispatcher this very moment
        now = utcnow()
        if job.cancel_requested:
            values: dict[str, Any] = {"state": "cancelled", "stage": "cancelled", "finished_at": now}
        elif not resume:
            values = {
                "state": "failed",
                "error": f"its worker process ({pid}) ended without a word",
                "finished_at": now,
            }
        elif job.attempts >= MAX_ATTEMPTS:
            values = {
                "state": "failed",
                "error": f"the service stopped while it ran, {job.attempts} times; not resumed again",
                "finished_at": now,
            }
        else:
            values = {"state": "queued", "stage": "resumed after the service restarted", "runner": ""}
        what = "the service restarted while this ran" if resume else "its worker process is gone"
        values["log"] = append_log(job.log, [f"jobs: {what}; {values['state']}"])
        values["updated_at"] = now
        seen = (Job.id == job.id, Job.state == "running", Job.runner == job.runner)
        touched += _count(session.execute(update(Job).where(*seen).values(**values)))
        session.commit()
    return touched


def sweep_leftovers(session: Session, settings: Settings) -> list[str]:
    """Remove what ended jobs left on disk: each ``jobs/ID/`` folder (a queued pass's frames) whose job is not
    queued or running, and, while no adaptation is queued or running anywhere, half-written versions
    (``model-sets/*/*.partial``) and this service's adaptation work folders (``work/``, a tenant's frames; another
    service's on the same host, with its own data folder, are its own). Return what went."""
    import shutil

    data = Path(settings.data_dir)
    active = {j.id: j.kind for j in session.scalars(select(Job).where(Job.state.in_(JOB_ACTIVE)))}
    session.commit()
    gone = []
    root = data / "jobs"
    stale = [p for p in root.iterdir() if p.is_dir() and p.name not in active] if root.is_dir() else []
    if "adaptation" not in active.values():
        stale += list((data / "model-sets").glob("*/*.partial"))
        stale += list((data / "work").glob("gsa-adaptation-*"))
    for path in stale:
        shutil.rmtree(path, ignore_errors=True)
        gone.append(path.name)
    return gone


def any_active(session: Session) -> bool:
    return bool(session.scalar(select(func.count()).select_from(Job).where(Job.state.in_(JOB_ACTIVE))))


def eta_s(job: Job, now: datetime | None = None) -> float | None:
    """Seconds left, from the time it has run and the share done; None until there is something to go on."""
    if job.state != "running" or job.started_at is None or not 0.02 <= job.progress < 1.0:
        return None
    started = job.started_at if job.started_at.tzinfo else job.started_at.replace(tzinfo=UTC)
    ran = ((now or utcnow()) - started).total_seconds()
    return round(max(0.0, ran * (1.0 - job.progress) / job.progress), 1)


@contextmanager
def _file_lock(path: Path) -> Iterator[None]:
    private_dir(path.parent)
    with open(path, "a") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


class Dispatcher:
    """Claims queued jobs and runs each in a child process, at most ``settings.job_workers`` on this host."""

    def __init__(self, settings: Settings, session_factory: Any) -> None:
        self.settings = settings
        self.session_factory = session_factory
        self.children: dict[str, subprocess.Popen[bytes]] = {}
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._stop = threading.Event()

    def stop(self, timeout: float = 5.0) -> None:
        """Stop claiming work (the server shutting down); running jobs go on in their own processes."""
        self._stop.set()
        self._wake.set()
        thread = self._thread
        if thread is not None:
            thread.join(timeout)
        for proc in self.children.values():  # each running worker goes on; its exit is collected, not left a zombie
            threading.Thread(target=proc.wait, name="gsa-jobs-reap", daemon=True).start()
        self.children = {}

    def nudge(self) -> None:
        """Say there is work: start the thread if it is not running, else wake it (a host that runs no jobs,
        GSA_JOB_WORKERS=0, leaves them to the hosts that do)."""
        if self.settings.job_workers == 0:
            return
        self._stop.clear()
        with self._lock:
            if self._thread is None or not self._thread.is_alive():
                self._thread = threading.Thread(target=self._loop, name="gsa-jobs", daemon=True)
                self._thread.start()
        self._wake.set()

    def _loop(self) -> None:
        idle = 0
        while not self._stop.is_set():
            try:
                busy = self._step()
            except Exception:  # a database that does not answer: try again, then give up until the next nudge
                busy = True
                idle += 1
                if idle > 120:
                    return
            else:
                idle = 0 if busy else idle + 1
            if not busy and idle >= 4:
                with self._lock:
                    self._thread = None
                return
            self._wake.wait(POLL_S)
            self._wake.clear()
        with self._lock:
            self._thread = None

    def _step(self) -> bool:
        """Reap finished children, claim what there is room for; say whether any work remains."""
        for job_id, proc in list(self.children.items()):
            code = proc.poll()
            if code is None:
                continue
            del self.children[job_id]
            try:  # what the worker started and left behind (killed, crashed) goes too: its group outlives it
                os.killpg(proc.pid, signal.SIGKILL)
            except OSError:
                pass
            with self.session_factory() as s:  # a worker that died without a word: say so (writes first, no read)
                now = utcnow()
                reason = f"the worker process ended with status {code} before finishing"
                if code < 0:
                    reason += f" (signal {-code}; out of memory kills with 9)"
                mine = (Job.id == job_id, Job.state == "running", Job.runner == f"{host()}:{proc.pid}")
                s.execute(
                    update(Job)
                    .where(*mine, Job.cancel_requested.is_(True))
                    .values(state="cancelled", stage="cancelled", finished_at=now, updated_at=now)
                )
                s.execute(
                    update(Job)
                    .where(*mine, Job.cancel_requested.is_(False))
                    .values(state="failed", error=reason, finished_at=now, updated_at=now)
                )
                s.commit()
        with _file_lock(Path(self.settings.data_dir) / "jobs" / "dispatch.lock"), self.session_factory() as s:
            recover(s, resume=False)  # a worker of this host that died unseen no longer holds a place
            running = [
                j for j in s.scalars(select(Job).where(Job.state == "running")) if j.runner.rpartition(":")[0] == host()
            ]
            room = self.settings.job_workers - len(running)
            busy = Counter(
                j.operator_id for j in s.scalars(select(Job).where(Job.state == "running"))
            )  # every host's: the share is the service's, not this host's
            waiting = list(s.scalars(select(Job).where(Job.state == "queued").order_by(Job.created_at, Job.id)))
            served = s.execute(
                select(Job.operator_id, func.max(Job.started_at))
                .where(Job.operator_id.in_({j.operator_id for j in waiting}), Job.started_at.is_not(None))
                .group_by(Job.operator_id)
            )
            queued = fair_order(waiting, busy, {op: t for op, t in served if t is not None})[: max(room, 0)]
            s.commit()  # the reads end here: each claim below writes first
            for job in queued:
                now = utcnow()
                claimed = _count(
                    s.execute(
                        update(Job)
                        .where(Job.id == job.id, Job.state == "queued")
                        .values(
                            state="running",
                            stage="starting",
                            runner=f"{host()}:0",
                            started_at=now,
                            updated_at=now,
                            attempts=Job.attempts + 1,
                        )
                    )
                )
                s.commit()
                if claimed:
                    proc = self._spawn(job.id)
                    self.children[job.id] = proc
                    s.execute(
                        update(Job)
                        .where(Job.id == job.id, Job.runner == f"{host()}:0")
                        .values(runner=f"{host()}:{proc.pid}")
                    )
                    s.commit()
            more = s.scalar(select(func.count()).select_from(Job).where(Job.state.in_(JOB_ACTIVE)))
        return bool(self.children) or bool(more)

    def _spawn(self, job_id: str) -> subprocess.Popen[bytes]:
        env = {**os.environ, "PYTHONUNBUFFERED": "1", "GSA_JOB_SETTINGS": self.settings.model_dump_json()}
        log = Path(self.settings.data_dir) / "jobs" / f"{job_id}.log"
        private_dir(log.parent)
        with os.fdopen(os.open(log, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o600), "ab") as out:
            out.write(f"jobs: {host()}:{os.getpid()} starts a worker for {job_id}\n".encode())
            out.flush()
            return subprocess.Popen(
                [sys.executable, "-m", "app.services.job_worker", job_id],
                stdout=out,
                stderr=subprocess.STDOUT,
                env=env,
                start_new_session=True,  # a Ctrl-C at the server's terminal is not the job's
                umask=0o077,  # what the job and its children write (data sets, versions, frames) is 0700 / 0600
            )

    def wait_idle(self, timeout: float) -> bool:
        """For tests and shutdown: wait until no child runs; say whether none does."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if not any(p.poll() is None for p in self.children.values()):
                return True
            time.sleep(0.1)
        return False


def settings_from_env() -> Settings:
    """The settings a worker was started with (``GSA_JOB_SETTINGS``, as the server had them), else the env's."""
    text = os.environ.get("GSA_JOB_SETTINGS")
    if not text:
        from app.core.config import get_settings

        return get_settings()
    return Settings.model_validate(json.loads(text))
