"""Model-set versions and adaptations: what answers each operator's target now, and the jobs that make versions.

Version 0 of a target's set is the folder the service was started with (GSA_MODEL_DIR, GSA_EXTRA_MODEL_DIRS),
shared and read-only. Each adaptation (``gsa adapt`` on the operator's labelled frames, run as a child process so
the service stays responsive) makes the next version under ``GSA_DATA_DIR/model-sets/TARGET/vN``, the operator's
own, not promoted. The tenancy:

- an operator promotes its own versions, for itself alone (a ``ModelPromotion`` row with its id as scope);
- an admin key may also promote any version as the shared default (scope "shared"): it answers every operator
  without a promotion of its own;
- no promotion at all: version 0.

Every request reads the promotions from the database, so every worker and host answers with the same version as
soon as it is promoted. A promotion passes a quality gate first (``Served.gate``): the files verified and a smoke
estimate run, or the promotion is refused.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import threading
from collections import OrderedDict
from pathlib import Path
from typing import Any

from sqlalchemy import delete, func, select
from sqlalchemy.orm import Session

from app.core.config import Settings
from app.db.models import SHARED_SCOPE, Job, ModelPromotion, ModelVersion, utcnow
from app.errors import Conflict, Forbidden, InputError, VersionUnusable

EPOCH = re.compile(r"epoch (\d+)/(\d+)")


def version_row(session: Session, target: str, version: int) -> ModelVersion | None:
    """The row of ``version`` of ``target`` (None for 0, the configured set); LookupError when there is none."""
    if version == 0:
        return None
    row = session.scalar(select(ModelVersion).where(ModelVersion.target == target, ModelVersion.version == version))
    if row is None:
        raise LookupError(version)
    return row


def _promoted_version(session: Session, scope: str, target: str) -> int | None:
    row = session.get(ModelPromotion, (scope, target))
    return None if row is None else int(row.version)


def shared_version(session: Session, target: str) -> int:
    """The version that answers ``target`` for every operator without a promotion of its own (0: none promoted)."""
    return _promoted_version(session, SHARED_SCOPE, target) or 0


def answering_version(session: Session, operator_id: str, target: str) -> int:
    """The version that answers ``target`` for ``operator_id``: its own promotion, else the shared default."""
    own = _promoted_version(session, operator_id, target)
    return own if own is not None else shared_version(session, target)


def answering_row(session: Session, operator_id: str, target: str) -> ModelVersion | None:
    """The row of the version that answers ``target`` for ``operator_id`` (None: the configured set)."""
    return version_row(session, target, answering_version(session, operator_id, target))


def visible(session: Session, operator_id: str, target: str, admin: bool = False) -> list[ModelVersion]:
    """The versions of ``target`` the operator may see, use and promote: its own and the shared default (an admin
    key: every operator's, since it chooses the shared default among them)."""
    q = select(ModelVersion).where(ModelVersion.target == target).order_by(ModelVersion.version)
    if admin:
        return list(session.scalars(q))
    shared = shared_version(session, target)
    return [r for r in session.scalars(q) if r.operator_id == operator_id or r.version == shared]


def usable_row(
    session: Session, operator_id: str, target: str, version: int, admin: bool = False
) -> ModelVersion | None:
    """The row of a version the operator may use (None for 0); LookupError for one it may not see or none at all."""
    if version == 0:
        return None
    for row in visible(session, operator_id, target, admin):
        if row.version == version:
            return row
    raise LookupError(version)


def promote(session: Session, *, operator_id: str, target: str, version: int, shared: bool = False) -> None:
    """Promote ``version`` of ``target`` for the operator alone, or (``shared``: an admin's) for every operator
    without a promotion of its own. Version 0 withdraws the promotion: the operator is answered by the shared
    default again, and the shared default is the configured set again. One statement, so concurrent promotions
    neither deadlock nor leave two answering."""
    scope = SHARED_SCOPE if shared else operator_id
    if version == 0:
        session.execute(delete(ModelPromotion).where(ModelPromotion.scope == scope, ModelPromotion.target == target))
        session.commit()
        return
    values = {"scope": scope, "target": target, "version": version, "promoted_at": utcnow(), "promoted_by": operator_id}
    dialect = session.get_bind().dialect.name
    if dialect == "postgresql":
        from sqlalchemy.dialects.postgresql import insert as pg_insert

        pg = pg_insert(ModelPromotion).values(**values)
        stmt: Any = pg.on_conflict_do_update(
            index_elements=["scope", "target"],
            set_={k: pg.excluded[k] for k in ("version", "promoted_at", "promoted_by")},
        )
    else:
        from sqlalchemy.dialects.sqlite import insert as sqlite_insert

        lite = sqlite_insert(ModelPromotion).values(**values)
        stmt = lite.on_conflict_do_update(
            index_elements=["scope", "target"],
            set_={k: lite.excluded[k] for k in ("version", "promoted_at", "promoted_by")},
        )
    session.execute(stmt)
    session.commit()


DEFAULT_LOADED = 4  # adapted versions kept loaded per process (about 220 MB each), the least recently used evicted


def promote_checked(
    session: Session,
    served: Served,
    checker: Any,
    *,
    operator_id: str,
    target: str,
    version: int,
    shared: bool,
    admin: bool,
) -> None:
    """Promote after the checks: ``Forbidden`` when ``shared`` without an admin key, LookupError for a version
    the caller may not see, ``Conflict`` naming why when the version fails the quality gate (``Served.gate``)."""
    if shared and not admin:
        raise Forbidden(
            "changing the shared default needs an admin key (gsa keys role ID admin, or GSA_ADMIN_API_KEYS); "
            "promote without shared=true to change what answers you alone"
        )
    row = usable_row(session, operator_id, target, version, admin=shared)
    if row is not None:
        problem = served.gate(row, checker)
        if problem:
            raise Conflict(f"version {version} of {target} was not promoted: {problem}")
    promote(session, operator_id=operator_id, target=target, version=version, shared=shared)


def delete_version(session: Session, settings: Settings, *, operator_id: str, target: str, version: int) -> None:
    """Delete one of the operator's own versions, with its folder: LookupError for one not its own (or none), a
    ``Conflict`` while any promotion names it (its own, another operator's pin, or the shared default)."""
    if version == 0:
        raise Conflict(f"version 0 of {target} is the configured set, shared and read-only; it cannot be deleted")
    row = version_row(session, target, version)
    assert row is not None
    if row.operator_id != operator_id:
        raise LookupError(version)
    named = session.scalars(
        select(ModelPromotion.scope).where(ModelPromotion.target == target, ModelPromotion.version == version)
    ).all()
    if named:
        who = "the shared default" if SHARED_SCOPE in named else "promoted"
        raise Conflict(f"version {version} of {target} is {who}: promote another (or 0) first, then delete it")
    session.execute(delete(ModelVersion).where(ModelVersion.id == row.id))
    session.commit()
    shutil.rmtree(Path(settings.data_dir) / row.dir, ignore_errors=True)


class Served:
    """The networks and checks that answer each operator and target: its promoted version's, or the configured
    set's.

    A version's networks and its calibration (its ``trust.json``: the radar it was adapted to) load on first
    use and stay loaded, at most ``max_loaded`` versions at once (the least recently used is dropped).
    """

    def __init__(
        self, data_dir: Path, threads: int | None = None, fit_threads: int = 0, max_loaded: int = DEFAULT_LOADED
    ) -> None:
        self.data_dir = Path(data_dir)
        self.threads = threads
        self.fit_threads = fit_threads
        self.max_loaded = max(1, max_loaded)
        self._loaded: OrderedDict[tuple[str, int], tuple[Any, Any]] = OrderedDict()
        self._lock = threading.Lock()

    def resolve(self, session: Session, model_sets: Any, checker: Any, operator_id: str) -> tuple[Any, Any]:
        """(Estimator, Checker) that answer the checker's target for ``operator_id`` (``answering_row``)."""
        return self.version(answering_row(session, operator_id, checker.model.name), model_sets, checker)

    def version(self, row: ModelVersion | None, model_sets: Any, checker: Any) -> tuple[Any, Any]:
        """(Estimator, Checker) of one version of the checker's target (None: version 0, the configured set)."""
        if row is None:
            return model_sets.for_target(checker.model.name), checker
        key = (row.target, row.version)
        with self._lock:
            if key in self._loaded:
                self._loaded.move_to_end(key)
                return self._loaded[key]
            try:
                loaded = self._load(self.data_dir / row.dir, checker)
            except Exception as exc:  # onnxruntime's, numpy's, json's: every way a folder on disk can fail
                raise VersionUnusable(
                    f"version {row.version} of {row.target}, which answers this request, cannot be loaded here "
                    f"({_without_paths(exc)}); promote another version, or 0 "
                    f"(POST /v1/model-sets/{row.target}/versions/0/promote)"
                ) from None
            self._loaded[key] = loaded
            while len(self._loaded) > self.max_loaded:
                self._loaded.popitem(last=False)
            return loaded

    def _load(self, folder: Path, base_checker: Any) -> tuple[Any, Any]:
        from inference.runtime import Estimator
        from inference.trust import TRUST_FILE, Calibration, Checker, card_radar_and_target

        est = Estimator.load(folder, threads=self.threads)
        radar, _ = card_radar_and_target(folder, est.img_size)
        path = folder / TRUST_FILE
        cal = Calibration.load(path) if path.is_file() else base_checker.calibration
        return est, Checker(base_checker.model, radar, cal, networks=True, threads=self.fit_threads)

    def gate(self, row: ModelVersion, base_checker: Any) -> str | None:
        """The promotion's quality gate: why ``row`` may not answer anyone, or None when it may. Its files are
        loaded afresh (each checked against the sha256 its card records, UNet++ against its export self-check) and
        one smoke estimate runs: a seeded frame through both networks, whose angles must be finite and in range."""
        import numpy as np

        try:
            est, _checker = self._load(self.data_dir / row.dir, base_checker)
            frame = np.random.default_rng(0).random((1, est.img_size, est.img_size), dtype=np.float32)
            out = est.estimate(frame)
        except Exception as exc:
            return f"version {row.version}'s files do not load: {_without_paths(exc)}"
        angles = np.asarray(out.angles_deg, np.float64)
        if angles.shape != (1, 3) or not np.isfinite(angles).all() or float(np.abs(angles).max()) > 360.0:
            return f"version {row.version}'s smoke estimate answered {angles.tolist()}, not three finite angles"
        return None


def _without_paths(exc: BaseException) -> str:
    """An error's first line with the server's absolute paths cut to their last part (no server path leaves)."""
    text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    return re.sub(r"(?:/[^/\s'\"]+)+/([^/\s'\"]+)", r"\1", text)[:300]


def load_answering(
    settings: Settings, session: Session, target: str, operator_id: str, version: int | None = None
) -> tuple[Any, Any]:
    """(Estimator, Checker) of ``target`` as the service answers ``operator_id`` (its promoted version), or of
    ``version`` (0: the configured set), loaded from the settings alone: what a job's worker process uses."""
    from inference.runtime import ModelSets
    from inference.trust import load_checkers

    sets = ModelSets.load(settings.model_dir, settings.extra_model_dir_list, threads=settings.ort_threads or None)
    checkers = load_checkers(
        settings.model_dir,
        sets.default.img_size,
        settings.target_model,
        settings.target_scale,
        settings.default_target,
        threads=settings.fit_threads,
    )
    row = answering_row(session, operator_id, target) if version is None else version_row(session, target, version)
    served = Served(settings.data_dir, threads=settings.ort_threads or None, fit_threads=settings.fit_threads)
    return served.version(row, sets, checkers.get(target))


def start(
    *,
    session: Session,
    settings: Settings,
    operator_id: str,
    target: str,
    base_dir: Path,
    options: dict[str, Any],
) -> Job:
    """Check the request and queue the adaptation as a job (``app.services.jobs``; one per operator and target at a
    time)."""
    from app.services import jobs, storage
    from app.services.labelled import summarise

    for field, asked, most, name in (
        ("max_minutes", options.get("max_minutes"), settings.max_adaptation_minutes, "GSA_MAX_ADAPTATION_MINUTES"),
        ("epochs", options.get("epochs"), settings.max_adaptation_epochs, "GSA_MAX_ADAPTATION_EPOCHS"),
    ):
        if asked is not None and asked > most:
            raise InputError(
                [field],
                f"{asked:g} is over this service's limit of {most:g} ({name}): one job worker is held that long",
            )
    summary = summarise(session=session, operator_id=operator_id, target=target)
    if summary.count < 4 or len(summary.per_scene) < 2:
        raise InputError(
            ["target"],
            f"you have {summary.count} labelled frames of {target} from {len(summary.per_scene)} scene(s); an "
            "adaptation needs at least 4, from 2 scenes or more (POST /v1/targets/{target}/labelled-frames)",
        )
    storage.check_room(session, settings, operator_id, storage.folder_bytes(base_dir), "the adapted version")
    return jobs.submit(
        session,
        operator_id=operator_id,
        kind="adaptation",
        key=f"adaptation:{operator_id}:{target}",
        busy_message=f"an adaptation of {target} of yours is already queued or running; wait for it (one at a time)",
        params={"target": target, "options": options, "frames": summary.count, "base_dir": str(base_dir)},
        engine="ray" if settings.ray_address else "local",
        cap=settings.quota_queued_jobs,
    )


ADAPTATION_WORK_PREFIX = "gsa-adaptation-"


def work_root(data_dir: Path | str) -> Path:
    """Where this service's adaptations work (a tenant's frames while ``gsa adapt`` runs): inside its own data
    folder, so a start-up sweep of another service on the same host (another data folder) never touches them."""
    root = Path(data_dir) / "work"
    root.mkdir(mode=0o700, parents=True, exist_ok=True)
    return root


def run_adaptation(ctx: Any) -> dict[str, Any]:
    """The job (``app.services.job_worker``): the labelled frames into a folder, ``gsa adapt`` in a child process,
    the version stored. A failure or a cancel leaves the served set as it was."""
    from app.services.labelled import frames_of
    from inference.labelled import write_frame

    settings = ctx.settings
    target, operator_id = ctx.params["target"], ctx.operator_id
    opts = dict(ctx.params.get("options") or {})
    work = Path(tempfile.mkdtemp(prefix=ADAPTATION_WORK_PREFIX, dir=work_root(settings.data_dir)))
    partial: Path | None = None
    proc: subprocess.Popen[str] | None = None
    try:
        with ctx.session_factory() as s:
            frames = frames_of(session=s, operator_id=operator_id, target=target, data_dir=settings.data_dir)
            row = answering_row(s, operator_id, target)  # the version that answers this operator now
            base_dir = Path(ctx.params["base_dir"])
            base, base_version = (settings.data_dir / row.dir, row.version) if row else (base_dir, 0)
            number = int(s.scalar(select(func.max(ModelVersion.version)).where(ModelVersion.target == target)) or 0) + 1
        ctx.report(stage=f"writing {len(frames)} labelled frames", progress=0.02)
        folder = work / "frames"
        folder.mkdir()
        for k in range(len(frames)):
            write_frame(
                folder / f"{k:05d}.npz",
                frames.frames[k],
                angles_deg=frames.angles_deg[k],
                scene=frames.scenes[k],
                normalised=True,
            )
        rel = Path("model-sets") / target / f"v{number}"
        out = settings.data_dir / rel
        partial = out.with_name(out.name + ".partial")
        shutil.rmtree(partial, ignore_errors=True)
        cmd = [sys.executable, "-m", "inference.training.adapt", "--frames", str(folder), "--base", str(base)]
        cmd += ["--out", str(partial), "--target", target]
        for key in ("epochs", "max_minutes", "sim_ratio", "validation_share", "seed", "lr_unet", "crop_px"):
            if opts.get(key) is not None:
                cmd += [f"--{key.replace('_', '-')}", str(opts[key])]
        if opts.get("train_swin"):
            cmd.append("--train-swin")
        if opts.get("map_only"):
            cmd.append("--map-only")
        elif opts.get("map"):
            cmd.append("--map")
        proc = subprocess.Popen(
            cmd,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            env={**os.environ, "PYTHONUNBUFFERED": "1", "GSA_RAY_ADDRESS": settings.ray_address},  # a cluster: there
        )
        assert proc.stdout is not None
        last = ""
        for line in proc.stdout:
            line = line.rstrip()
            if line.strip():
                last = line
            ctx.say(line)
            at = line.find("adapt: ")  # on a Ray cluster the line comes prefixed with its worker
            if at >= 0:
                stage = line[at + len("adapt: ") :]
                m = EPOCH.search(line)
                if m:
                    ctx.report(stage, int(m.group(1)), int(m.group(2)), 0.1 + 0.75 * int(m.group(1)) / int(m.group(2)))
                elif "exporting" in line:
                    ctx.report(stage, progress=0.88)
                elif "recalibrating" in line:
                    ctx.report(stage, progress=0.93)
                else:
                    ctx.report(stage)
            else:
                ctx.check()
        code = proc.wait()
        if code != 0:
            raise RuntimeError(last or f"gsa adapt exited with {code}")
        card_path = partial / "model_card.json"
        card = json.loads(card_path.read_text())
        card["version"] = {"target": target, "number": number, "base": base_version}
        card_path.write_text(json.dumps(card, indent=1))
        shutil.rmtree(out, ignore_errors=True)
        partial.rename(out)
        partial = None
        rec = card.get("adaptation", {})
        summary = {
            "labelled_frames": rec.get("labelled", {}).get("frames"),
            "train_scenes": rec.get("labelled", {}).get("train_scenes"),
            "validation_scenes": rec.get("labelled", {}).get("validation_scenes"),
            "list_sha256": rec.get("labelled", {}).get("list_sha256"),
            "before": rec.get("before"),
            "after": rec.get("after"),
            "calibration": rec.get("calibration"),
            "cpu_minutes": rec.get("cpu_minutes"),
            "export": rec.get("export"),
        }
        if card.get("map"):
            from inference.reflectivity.sets import summary as map_summary

            summary["map"] = map_summary(card["map"])
        with ctx.session_factory() as s:
            s.add(
                ModelVersion(
                    target=target,
                    version=number,
                    created_at=utcnow(),
                    operator_id=operator_id,
                    base_version=base_version,
                    dir=str(rel),
                    summary=summary,
                )
            )
            s.commit()
        return {"version": number, "target": target, "url": f"/v1/model-sets/{target}"}
    finally:
        if proc is not None and proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
        if partial is not None:
            shutil.rmtree(partial, ignore_errors=True)
        shutil.rmtree(work, ignore_errors=True)
