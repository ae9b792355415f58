"""Model-set versions and adaptations: what answers a target now, and the jobs that make new versions.

Version 0 of a target's set is the folder the service was started with (GSA_MODEL_DIR, GSA_EXTRA_MODEL_DIRS);
each adaptation (``gsa adapt`` on the operator's labelled frames, run as a child process so the service stays
responsive) makes the next version under ``GSA_DATA_DIR/model-sets/TARGET/vN``, not promoted. One version per
target is promoted (a row's flag; none promoted: version 0); every request reads it from the database, so every
worker and host answers with the same version as soon as it is promoted, and rolls back as soon as 0 is.
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
from pathlib import Path
from typing import Any

from sqlalchemy import func, select, update
from sqlalchemy.orm import Session

from app.core.config import Settings
from app.db.models import Job, ModelVersion, utcnow
from app.errors import InputError

EPOCH = re.compile(r"epoch (\d+)/(\d+)")


def promoted(session: Session, target: str) -> ModelVersion | None:
    return session.scalar(select(ModelVersion).where(ModelVersion.target == target, ModelVersion.promoted.is_(True)))


def versions(session: Session) -> list[ModelVersion]:
    return list(session.scalars(select(ModelVersion).order_by(ModelVersion.target, ModelVersion.version)))


def promote(session: Session, target: str, version: int) -> None:
    """Promote ``version`` of ``target`` (0: the configured set, a rollback); the others are demoted with it."""
    if version != 0:
        row = session.scalar(select(ModelVersion).where(ModelVersion.target == target, ModelVersion.version == version))
        if row is None:
            raise LookupError(version)
    session.execute(update(ModelVersion).where(ModelVersion.target == target).values(promoted=False))
    if version != 0:
        session.execute(
            update(ModelVersion)
            .where(ModelVersion.target == target, ModelVersion.version == version)
            .values(promoted=True)
        )
    session.commit()


class Served:
    """The networks and checks that answer each target: its promoted version's, or the configured set's.

    A version's networks and its calibration (its ``trust.json``: the radar it was adapted to) load on first
    use and stay loaded.
    """

    def __init__(self, data_dir: Path, threads: int | None = None, fit_threads: int = 0) -> None:
        self.data_dir = Path(data_dir)
        self.threads = threads
        self.fit_threads = fit_threads
        self._loaded: dict[tuple[str, int], tuple[Any, Any]] = {}
        self._lock = threading.Lock()

    def resolve(self, session: Session, model_sets: Any, checker: Any) -> tuple[Any, Any]:
        """(Estimator, Checker) for the checker's target: its promoted version's where one is promoted."""
        return self.version(promoted(session, checker.model.name), model_sets, checker)

    def version(self, row: ModelVersion | None, model_sets: Any, checker: Any) -> tuple[Any, Any]:
        """(Estimator, Checker) of one version of the checker's target (None: version 0, the configured set)."""
        if row is None:
            return model_sets.for_target(checker.model.name), checker
        key = (row.target, row.version)
        with self._lock:
            if key not in self._loaded:
                self._loaded[key] = self._load(self.data_dir / row.dir, checker)
            return self._loaded[key]

    def _load(self, folder: Path, base_checker: Any) -> tuple[Any, Any]:
        from inference.runtime import Estimator
        from inference.trust import TRUST_FILE, Calibration, Checker, card_radar_and_target

        est = Estimator.load(folder, threads=self.threads)
        radar, _ = card_radar_and_target(folder, est.img_size)
        path = folder / TRUST_FILE
        cal = Calibration.load(path) if path.is_file() else base_checker.calibration
        return est, Checker(base_checker.model, radar, cal, networks=True, threads=self.fit_threads)


def load_answering(settings: Settings, session: Session, target: str, version: int | None = None) -> tuple[Any, Any]:
    """(Estimator, Checker) of ``target`` as the service answers it (its promoted version), or of ``version``
    (0: the configured set), loaded from the settings alone: what a job's worker process uses."""
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
    if version is None:
        row = promoted(session, target)
    elif version == 0:
        row = None
    else:
        row = session.scalar(select(ModelVersion).where(ModelVersion.target == target, ModelVersion.version == version))
        if row is None:
            raise LookupError(version)
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
    """Check the request and queue the adaptation as a job (``app.services.jobs``; one per target at a time)."""
    from app.services import jobs
    from app.services.labelled import summarise

    summary = summarise(session=session, operator_id=operator_id, target=target)
    if summary.count < 4 or len(summary.per_scene) < 2:
        raise InputError(
            ["target"],
            f"you have {summary.count} labelled frames of {target} from {len(summary.per_scene)} scene(s); an "
            "adaptation needs at least 4, from 2 scenes or more (POST /v1/targets/{target}/labelled-frames)",
        )
    return jobs.submit(
        session,
        operator_id=operator_id,
        kind="adaptation",
        key=f"adaptation:{target}",
        busy_message=f"an adaptation of {target} is already queued or running; wait for it (one at a time)",
        params={"target": target, "options": options, "frames": summary.count, "base_dir": str(base_dir)},
        engine="ray" if settings.ray_address else "local",
    )


def run_adaptation(ctx: Any) -> dict[str, Any]:
    """The job (``app.services.job_worker``): the labelled frames into a folder, ``gsa adapt`` in a child process,
    the version stored. A failure or a cancel leaves the served set as it was."""
    from app.services.labelled import frames_of
    from inference.labelled import write_frame

    settings = ctx.settings
    target, operator_id = ctx.params["target"], ctx.operator_id
    opts = dict(ctx.params.get("options") or {})
    work = Path(tempfile.mkdtemp(prefix="gsa-adaptation-"))
    partial: Path | None = None
    proc: subprocess.Popen[str] | None = None
    try:
        with ctx.session_factory() as s:
            frames = frames_of(session=s, operator_id=operator_id, target=target, data_dir=settings.data_dir)
            row = promoted(s, target)
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
                    promoted=False,
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
