"""Data sets simulated as jobs (``POST /v1/datasets``): ``inference.simulation.dataset`` on the job's engine.

The set is written under ``GSA_DATA_DIR/datasets/JOB_ID`` as ``gsa simulate`` writes it (shards, manifest, hashes);
on a Ray cluster (``GSA_RAY_ADDRESS``) each shard is a Ray task and the files are byte-identical to a local run.
A job resumed after a restart keeps the shards it had written.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

from sqlalchemy.orm import Session

from app.core.config import Settings
from app.db.models import Job
from app.errors import InputError
from app.schemas import DatasetCreate
from app.services import jobs, storage


def spec_and_radar(params: dict[str, Any]) -> tuple[Any, Any]:
    """The simulator's DatasetSpec and Radar from a request's fields; bad input: a 422 naming the field."""
    from inference.errors import InferenceError
    from inference.simulation.dataset import DatasetSpec
    from inference.simulation.radar import Radar

    radar_in = params.get("radar") or {}
    try:
        radar = Radar(
            radar_in.get("carrier_hz", 15e9),
            radar_in.get("bandwidth_hz", 1.6e9),
            radar_in.get("n_range", 256),
            radar_in.get("n_azimuth", 256),
            radar_in.get("aperture_deg", 5.1),
        )
    except InferenceError as exc:
        raise InputError(["radar", exc.field or "radar"], str(exc)) from None
    try:
        spec = DatasetSpec(
            n=params["n"],
            seed=params.get("seed", 0),
            snr_min_db=params.get("snr_min_db"),
            snr_max_db=params.get("snr_max_db"),
            max_angle_deg=params.get("max_angle_deg", 45.0),
            attitudes=params.get("attitudes", "cube"),
            shard_size=params.get("shard_size", 250),
            n_train=params.get("n_train"),
            variety=params.get("variety"),
            variety_share=params.get("variety_share", 1.0),
            physics=params.get("physics", "centres"),
            physics_share=params.get("physics_share", 1.0),
        )
    except InferenceError as exc:
        field = {"snr_db": "snr_min_db"}.get(exc.field or "", exc.field or "n")
        raise InputError([field], str(exc)) from None
    return spec, radar


def submit_dataset(*, session: Session, settings: Settings, operator_id: str, dataset_in: DatasetCreate) -> Job:
    """Check the request (a bad one is a 422 now, not a failed job later) and queue it."""
    params = dataset_in.model_dump(mode="json")
    spec, radar = spec_and_radar(params)
    size_gb = spec.n * (radar.n_range * radar.n_azimuth * (2 + 1 / 8) + 64) / 1e9  # float16 frames, packed labels
    if size_gb > settings.max_dataset_gb:
        raise InputError(
            ["n"],
            f"{spec.n} frames of {radar.n_range} x {radar.n_azimuth} make {size_gb:.1f} GB, over GSA_MAX_DATASET_GB "
            f"({settings.max_dataset_gb:g}): ask for fewer frames, or smaller ones",
        )
    storage.check_room(session, settings, operator_id, int(size_gb * 1e9), f"a data set of {spec.n} frames")
    shards = -(-spec.n // spec.shard_size)
    return jobs.submit(
        session,
        operator_id=operator_id,
        kind="dataset",
        params=params,
        total=spec.n,
        stage=f"queued: {spec.n} frames in {shards} shards",
        engine="ray" if settings.ray_address else "local",
        cap=settings.quota_queued_jobs,
    )


def dataset_dir(settings: Settings, job_id: str) -> Path:
    return Path(settings.data_dir) / "datasets" / job_id


def run_dataset(ctx: Any) -> dict[str, Any]:
    """The job: simulate the set shard by shard on the engine, reporting each shard; resumable."""
    from inference.engine import describe, engine_for
    from inference.simulation.dataset import generate

    spec, radar = spec_and_radar(ctx.params)
    out = dataset_dir(ctx.settings, ctx.id)
    shutil.rmtree(out, ignore_errors=True)  # a set a stopped run finished but did not report: made again
    ctx.report(stage=f"connecting to {ctx.settings.ray_address}" if ctx.settings.ray_address else "starting")
    engine = engine_for(ctx.settings.ray_address, workers=ctx.settings.job_simulation_workers or None)
    where = describe(engine)
    ctx.say(f"dataset: {spec.n} frames, shards of {spec.shard_size}, on {where['engine']} ({where['workers']} CPUs)")
    ctx.report(stage=f"simulating on {where['engine']}", done=0, total=spec.n)

    def on_shard(done: int, total: int) -> None:
        ctx.report(stage=f"simulating on {where['engine']}: {done}/{total} frames", done=done, total=total)

    try:
        manifest = generate(spec, out, radar, progress=False, engine=engine, on_shard=on_shard, resume=True)
    except BaseException:  # cancelled or failed: nothing half made is left (a killed worker's shards stay, resumed)
        shutil.rmtree(out.with_name(out.name + ".partial"), ignore_errors=True)
        raise
    ctx.say(f"dataset: {manifest['frames_per_s']} frames/s, content sha256 {manifest['content_sha256'][:16]}")
    return {
        "dir": str(out.relative_to(ctx.settings.data_dir)),
        "frames": manifest["frames"],
        "shards": len(manifest["shards"]),
        "content_sha256": manifest["content_sha256"],
        "frames_per_s": manifest["frames_per_s"],
        **where,
    }
