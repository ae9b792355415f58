"""Jobs (``/v1/jobs``): long work's state, progress and result; and the data-set request, a job's kind."""

from __future__ import annotations

from datetime import datetime
from typing import TYPE_CHECKING, Any, Literal

from pydantic import Field, field_validator

from app.schemas.common import Described, Strict, Text, utc_or_none

if TYPE_CHECKING:
    from app.db.models import Job

RESULT_URLS = {
    "campaign": "/v1/campaigns/{campaign_id}",
    "adaptation": "/v1/model-sets/{target}",
    "dataset": "/v1/jobs/{job_id}",
    "reestimate": "/v1/estimates",
    "pass": "/v1/passes/{pass_id}",
}


class JobPublic(Described):
    id: str
    """the job's id"""
    kind: str
    """adaptation, dataset, campaign, reestimate or pass"""
    state: str
    """queued, running, done, failed or cancelled"""
    stage: str
    """what it is doing now, in words"""
    progress: float
    """0 to 1"""
    done: int
    """items done (frames, epochs, stretches: the stage says which)"""
    total: int
    """items in all (0: not known yet)"""
    eta_s: float | None = None
    """seconds left, from the time it has run and the share done (null until there is something to go on)"""
    created_at: datetime
    """when it was asked for (UTC)"""
    started_at: datetime | None = None
    """when its latest run started (UTC)"""
    updated_at: datetime | None = None
    """its worker's last word (UTC): a heartbeat"""
    finished_at: datetime | None = None
    """when it ended (UTC)"""
    engine: str
    """where its work runs: local (this host's worker processes) or ray (GSA_RAY_ADDRESS)"""
    attempts: int
    """how often it was started (more than 1: resumed after a restart)"""
    cancel_requested: bool
    """a cancel was asked for and the worker has not stopped yet"""
    params: dict[str, Any]
    """what was asked for"""
    result: dict[str, Any] | None = None
    """what it made, once done"""
    result_url: str | None = None
    """where the result is, once done"""
    error: str | None = None
    """why it failed"""
    log_tail: str
    """the last lines of its log"""

    @classmethod
    def from_row(cls, row: Job) -> JobPublic:
        from app.services.jobs import eta_s

        result = dict(row.result) if row.result is not None else None
        url = None
        if row.state == "done" and result is not None:
            template = RESULT_URLS.get(row.kind)
            try:
                url = template.format(job_id=row.id, **result) if template else None
            except KeyError:
                url = None
        params = {k: v for k, v in dict(row.params).items() if k != "base_dir"}
        return cls(
            id=row.id,
            kind=row.kind,
            state=row.state,
            stage=row.stage,
            progress=row.progress,
            done=row.done,
            total=row.total,
            eta_s=eta_s(row),
            created_at=utc_or_none(row.created_at) or row.created_at,
            started_at=utc_or_none(row.started_at),
            updated_at=utc_or_none(row.updated_at),
            finished_at=utc_or_none(row.finished_at),
            engine=row.engine,
            attempts=row.attempts,
            cancel_requested=row.cancel_requested,
            params=params,
            result=result,
            result_url=url,
            error=row.error,
            log_tail=row.log,
        )


class JobsPublic(Described):
    data: list[JobPublic]
    """the jobs of this page, newest first"""
    count: int
    """how many jobs match in all"""


class DatasetRadar(Strict):
    """The radar the frames are simulated for (default: the shipped networks' radar)."""

    carrier_hz: float = Field(default=15e9, ge=1e8, le=1e12)
    """carrier frequency"""
    bandwidth_hz: float = Field(default=1.6e9, ge=1e6, le=1e11)
    """bandwidth (range resolution c / 2B)"""
    n_range: int = Field(default=256, ge=8, le=1024)
    """range cells (rows)"""
    n_azimuth: int = Field(default=256, ge=8, le=1024)
    """cross-range cells (columns); a multiple of 8"""
    aperture_deg: float = Field(default=5.1, ge=0.01, le=45)
    """synthetic aperture"""

    @field_validator("n_azimuth")
    @classmethod
    def _whole_bytes(cls, value: int) -> int:
        if value % 8:
            raise ValueError(f"must be a multiple of 8 (labels are stored 8 cells a byte); {value} is not")
        return value


class DatasetCreate(Strict):
    """A labelled data set to simulate (``gsa simulate``'s options): sharded, hashed, the same bytes on any engine."""

    n: int = Field(ge=1, le=1_000_000)
    """frames"""
    seed: int = Field(default=0, ge=0, le=2**31)
    """the set's seed: frame i's truth and noise are a function of (seed, i) alone"""
    snr_min_db: float | None = Field(default=-3.0, ge=-40, le=80)
    """lowest SNR (with snr_max_db; both null: noise-free frames)"""
    snr_max_db: float | None = Field(default=15.0, ge=-40, le=80)
    """highest SNR"""
    max_angle_deg: float = Field(default=45.0, ge=0, le=89)
    """each Euler angle uniform within plus or minus this (attitudes cube)"""
    attitudes: Literal["cube", "so3"] = "cube"
    """cube: the Euler angles within max_angle_deg; so3: uniform over every rotation"""
    shard_size: int = Field(default=250, ge=1, le=10_000)
    """frames per shard (each shard is one task of the engine)"""
    n_train: int | None = Field(default=None, ge=0)
    """split after this many training frames (the rest the test set)"""
    variety: Literal["robust"] | None = None
    """draw each frame's scattering from this preset"""
    variety_share: float = Field(default=1.0, ge=0.001, le=1)
    """under variety, the share of frames drawn from the preset"""
    physics: Literal["centres", "po"] = "centres"
    """centres (scattering centres) or po (physical optics on the target's facets)"""
    physics_share: float = Field(default=1.0, ge=0.001, le=1)
    """under po, the share of frames made by physical optics"""
    radar: DatasetRadar = Field(default_factory=DatasetRadar)
    """the radar"""


class ReestimationCreate(Strict):
    """Which stored estimates to read again, and with which version of the target's model set."""

    version: int = Field(ge=0, le=100_000)
    """the version to read them with (0: the configured set; GET /v1/model-sets lists them)"""
    plan_id: Text | None = Field(default=None, max_length=36)
    """only the estimates tied to this plan"""
    limit: int = Field(default=1000, ge=1, le=100_000)
    """at most this many, oldest first"""
