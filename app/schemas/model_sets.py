"""Model sets: each target's versions (the configured set and its adaptations), which one answers, adaptation jobs."""

from __future__ import annotations

from datetime import datetime
from typing import TYPE_CHECKING, Any

from pydantic import Field, ValidationInfo, field_validator

from app.schemas.common import Described, Strict, utc_or_none
from inference.training.options import crop_problem

if TYPE_CHECKING:
    from app.db.models import Job, ModelVersion


class AdaptationCreate(Strict):
    """How to adapt (every field optional; ``gsa adapt``'s defaults)."""

    sim_ratio: float | None = Field(default=None, ge=0, le=20)
    """simulated frames mixed in per labelled frame, so what the simulator taught is kept (default 1)"""
    epochs: int | None = Field(default=None, ge=1, le=1000)
    """at most this many epochs (default 30)"""
    max_minutes: float | None = Field(default=None, ge=0.1, le=24 * 60)
    """stop after the epoch in which this runs out (default 25)"""
    validation_share: float | None = Field(default=None, ge=0.05, le=0.8)
    """share of the frames held out for validation and trust calibration, by whole scenes (default 0.3)"""
    seed: int | None = Field(default=None, ge=0, le=2**31)
    """the split's and training's seed (default 0)"""
    train_swin: bool | None = None
    """also fine-tune Swin's last stage (default: UNet++ alone, where a radar's look enters)"""
    lr_unet: float | None = Field(default=None, ge=1e-8, lt=1)
    """UNet++'s Adam rate (default 3e-5)"""
    map: bool | None = None
    """also build the reflectivity map from the frames beside the fine-tuning (default false; a few CPU minutes)"""
    map_only: bool | None = None
    """only build the map: the base version's networks as they are, plus a map of this radar's reflectivity learnt
    from the labelled frames (a few CPU minutes instead of the fine-tuning's up to 30; needs frames from 2 scenes)"""
    crop_px: int | None = Field(default=None, ge=0, le=4096)
    """train UNet++ on square windows of this many pixels about the target, a multiple of 16 from 32; 0 whole
    frames (default 0); not with ``train_swin``, since Swin reads whole frames"""

    @field_validator("crop_px")
    @classmethod
    def _window(cls, value: int | None, info: ValidationInfo) -> int | None:
        # gsa adapt's own rule (train_swin is declared before crop_px, so it is already read)
        problem = crop_problem(value or 0, bool(info.data.get("train_swin")))
        if problem:
            raise ValueError(problem)
        return value


class AdaptationPublic(Described):
    id: str
    """the job's id (the adaptation is a job: ``GET /v1/jobs/{id}``, cancelled by ``DELETE /v1/jobs/{id}``)"""
    job_url: str
    """the job's own page in the API"""
    target: str
    """the target whose set is adapted"""
    state: str
    """queued, running, done, failed or cancelled"""
    stage: str
    """what it is doing now, in words"""
    progress: float
    """0 to 1"""
    created_at: datetime
    """when it was asked for (UTC)"""
    finished_at: datetime | None = None
    """when it ended (UTC)"""
    frames: int
    """the labelled frames it learns from (the caller's, of this target)"""
    options: dict[str, Any]
    """the options asked for"""
    version: int | None = None
    """the version it made, once done (not promoted: POST .../versions/{version}/promote)"""
    error: str | None = None
    """why it failed; the served set is unchanged"""
    log: str
    """the last lines of the adaptation's output"""

    @classmethod
    def from_row(cls, row: Job) -> AdaptationPublic:
        params, result = dict(row.params), dict(row.result or {})
        return cls(
            id=row.id,
            job_url=f"/v1/jobs/{row.id}",
            target=str(params.get("target", "")),
            state=row.state,
            stage=row.stage,
            progress=row.progress,
            created_at=utc_or_none(row.created_at) or row.created_at,
            finished_at=utc_or_none(row.finished_at),
            frames=int(params.get("frames", 0)),
            options=dict(params.get("options") or {}),
            version=result.get("version"),
            error=row.error,
            log=row.log,
        )


class ModelVersionPublic(Described):
    version: int
    """the version (0: the set the service was started with)"""
    promoted: bool
    """whether it answers you for this target now"""
    mine: bool = False
    """whether you made it (your adaptation); version 0 and the shared default are not"""
    shared_default: bool = False
    """whether it answers every operator without a promotion of its own (an admin key chooses it)"""
    created_at: datetime | None = None
    """when it was made (UTC; none for version 0)"""
    base_version: int | None = None
    """the version it was adapted from"""
    summary: dict[str, Any] = Field(default_factory=dict)
    """how it was made: labelled frames and scenes (with a sha256 of their list), held-out figures before and after,
    the trust calibration, CPU minutes (only of your own versions, or to an admin key); version 0: its networks'
    identity"""

    @classmethod
    def from_row(
        cls, row: ModelVersion, *, answering: int, shared: int, operator_id: str, admin: bool
    ) -> ModelVersionPublic:
        mine = row.operator_id == operator_id
        return cls(
            version=row.version,
            promoted=row.version == answering,
            mine=mine,
            shared_default=row.version == shared,
            created_at=utc_or_none(row.created_at),
            base_version=row.base_version,
            summary=dict(row.summary) if mine or admin else {},
        )


class ModelSetPublic(Described):
    target: str
    """the target the set was trained on"""
    answering_version: int
    """the version that answers you for this target now: yours where you promoted one, else the shared default"""
    shared_version: int
    """the shared default: what answers every operator without a promotion of its own (0: the configured set)"""
    versions: list[ModelVersionPublic]
    """the versions you may see, 0 first: yours and the shared default (an admin key: every operator's)"""


class ModelSetsPublic(Described):
    data: list[ModelSetPublic]
    """one entry per target with a model set"""
