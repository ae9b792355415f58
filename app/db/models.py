"""SQLAlchemy 2 tables. Every stored record belongs to one operator."""

from __future__ import annotations

import uuid
from datetime import UTC, datetime
from typing import Any

from sqlalchemy import (
    JSON,
    Boolean,
    DateTime,
    Float,
    ForeignKey,
    Index,
    Integer,
    LargeBinary,
    String,
    Text,
    UniqueConstraint,
    text,
)
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column


def utcnow() -> datetime:
    return datetime.now(UTC)


def new_id() -> str:
    return str(uuid.uuid4())


class Base(DeclarativeBase):
    pass


class Operator(Base):
    __tablename__ = "operators"

    id: Mapped[str] = mapped_column(String(36), primary_key=True, default=new_id)
    name: Mapped[str] = mapped_column(String(200), unique=True)
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)


class ApiKey(Base):
    __tablename__ = "api_keys"

    id: Mapped[str] = mapped_column(String(36), primary_key=True, default=new_id)
    operator_id: Mapped[str] = mapped_column(ForeignKey("operators.id", ondelete="CASCADE"), index=True)
    name: Mapped[str] = mapped_column(String(200))
    prefix: Mapped[str] = mapped_column(String(16), index=True)
    key_hash: Mapped[str] = mapped_column(String(64), unique=True)
    hash_scheme: Mapped[str] = mapped_column(String(16), default="hmac-sha256")
    # "operator": the operator's own objects; "admin": also the shared default model sets (``gsa keys role``).
    role: Mapped[str] = mapped_column(String(16), default="operator", server_default="operator")
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)
    revoked_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True), nullable=True)


class Plan(Base):
    __tablename__ = "plans"
    __table_args__ = (Index("ix_plans_operator_created", "operator_id", "created_at"),)

    id: Mapped[str] = mapped_column(String(36), primary_key=True, default=new_id)
    operator_id: Mapped[str] = mapped_column(ForeignKey("operators.id", ondelete="CASCADE"))
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)
    target_name: Mapped[str] = mapped_column(String(200), index=True)
    observer_name: Mapped[str] = mapped_column(String(200))
    station_name: Mapped[str] = mapped_column(String(200))
    t_access: Mapped[datetime | None] = mapped_column(DateTime(timezone=True), nullable=True)
    miss_km: Mapped[float | None] = mapped_column(Float, nullable=True)
    request: Mapped[dict[str, Any]] = mapped_column(JSON)
    result: Mapped[dict[str, Any]] = mapped_column(JSON)


class PlanExport(Base):
    """One export of a plan (``opm``, ``oem.xml``, ``pointing.csv``...) as written when the plan was made,
    zlib-compressed: served as stored, so an export costs a read, not a plan (``app.services.exports``)."""

    __tablename__ = "plan_exports"

    plan_id: Mapped[str] = mapped_column(ForeignKey("plans.id", ondelete="CASCADE"), primary_key=True)
    name: Mapped[str] = mapped_column(String(32), primary_key=True)
    body: Mapped[bytes] = mapped_column(LargeBinary)
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)


class Campaign(Base):
    """A series of GSA scenes (``POST /v1/campaigns``): the request as validated and the typed result."""

    __tablename__ = "campaigns"
    __table_args__ = (Index("ix_campaigns_operator_created", "operator_id", "created_at"),)

    id: Mapped[str] = mapped_column(String(36), primary_key=True, default=new_id)
    operator_id: Mapped[str] = mapped_column(ForeignKey("operators.id", ondelete="CASCADE"))
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)
    target_name: Mapped[str] = mapped_column(String(200), index=True)
    observer_name: Mapped[str] = mapped_column(String(200))
    station_name: Mapped[str] = mapped_column(String(200))
    scenes: Mapped[int] = mapped_column(Integer)
    dv_total_m_s: Mapped[float] = mapped_column(Float)
    first_access: Mapped[datetime | None] = mapped_column(DateTime(timezone=True), nullable=True)
    request: Mapped[dict[str, Any]] = mapped_column(JSON)
    result: Mapped[dict[str, Any]] = mapped_column(JSON)


class Estimate(Base):
    __tablename__ = "estimates"
    __table_args__ = (Index("ix_estimates_operator_created", "operator_id", "created_at"),)

    id: Mapped[str] = mapped_column(String(36), primary_key=True, default=new_id)
    operator_id: Mapped[str] = mapped_column(ForeignKey("operators.id", ondelete="CASCADE"))
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)
    plan_id: Mapped[str | None] = mapped_column(ForeignKey("plans.id", ondelete="SET NULL"), nullable=True, index=True)
    observed_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True), nullable=True)
    input_name: Mapped[str] = mapped_column(String(255))
    input_sha256: Mapped[str] = mapped_column(String(64), index=True)
    shape: Mapped[list[int]] = mapped_column(JSON)
    dtype: Mapped[str] = mapped_column(String(32))
    snr_db: Mapped[float | None] = mapped_column(Float, nullable=True)
    result: Mapped[dict[str, Any]] = mapped_column(JSON)
    original_sha256: Mapped[str] = mapped_column(String(64))
    enhanced_sha256: Mapped[str] = mapped_column(String(64))


class Pass(Base):
    """A pass's frames fused into one attitude (``POST /v1/passes``): the answer and every frame's part in it."""

    __tablename__ = "passes"
    __table_args__ = (Index("ix_passes_operator_created", "operator_id", "created_at"),)

    id: Mapped[str] = mapped_column(String(36), primary_key=True, default=new_id)
    operator_id: Mapped[str] = mapped_column(ForeignKey("operators.id", ondelete="CASCADE"))
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)
    plan_id: Mapped[str | None] = mapped_column(ForeignKey("plans.id", ondelete="SET NULL"), nullable=True, index=True)
    result: Mapped[dict[str, Any]] = mapped_column(JSON)


class GroundStation(Base):
    """A named radar site an operator stores once and names in plans (``/v1/stations``)."""

    __tablename__ = "stations"
    __table_args__ = (
        UniqueConstraint("operator_id", "name", name="uq_stations_operator_name"),
        UniqueConstraint("operator_id", "name_key", name="uq_stations_operator_name_key"),
    )

    id: Mapped[str] = mapped_column(String(36), primary_key=True, default=new_id)
    operator_id: Mapped[str] = mapped_column(ForeignKey("operators.id", ondelete="CASCADE"))
    name: Mapped[str] = mapped_column(String(200))
    # What names are compared by (app.schemas.common.name_key): "GS", "gs" and full-width "GS" are one station.
    name_key: Mapped[str] = mapped_column(String(800))
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)
    station: Mapped[dict[str, Any]] = mapped_column(JSON)


class LabelledFrame(Base):
    """A radar frame with the attitude an optical observer measured (``/v1/targets/{target}/labelled-frames``).

    The frame is stored as the models' input (a PNG blob, like an estimate's); ``angles_deg`` is the label in the
    frame's observation frame, computed from ``quaternion_j2000`` and the plan's geometry where the label came so.
    """

    __tablename__ = "labelled_frames"
    __table_args__ = (
        Index("ix_labelled_operator_target", "operator_id", "target", "created_at"),
        UniqueConstraint("operator_id", "target", "input_sha256", name="uq_labelled_operator_target_input"),
    )

    id: Mapped[str] = mapped_column(String(36), primary_key=True, default=new_id)
    operator_id: Mapped[str] = mapped_column(ForeignKey("operators.id", ondelete="CASCADE"))
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)
    target: Mapped[str] = mapped_column(String(200))
    scene: Mapped[str] = mapped_column(String(200), index=True)
    plan_id: Mapped[str | None] = mapped_column(ForeignKey("plans.id", ondelete="SET NULL"), nullable=True, index=True)
    campaign_id: Mapped[str | None] = mapped_column(
        ForeignKey("campaigns.id", ondelete="SET NULL"), nullable=True, index=True
    )
    station_name: Mapped[str | None] = mapped_column(String(200), nullable=True)
    observed_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True), nullable=True)
    input_name: Mapped[str] = mapped_column(String(255))
    input_sha256: Mapped[str] = mapped_column(String(64))
    angles_deg: Mapped[list[float]] = mapped_column(JSON)
    quaternion_j2000: Mapped[list[float] | None] = mapped_column(JSON, nullable=True)
    attitude_sigma_deg: Mapped[float | None] = mapped_column(Float, nullable=True)
    snr_db: Mapped[float | None] = mapped_column(Float, nullable=True)
    cells_m: Mapped[list[float] | None] = mapped_column(JSON, nullable=True)
    frame_sha256: Mapped[str] = mapped_column(String(64))


class ModelVersion(Base):
    """An adapted version of a target's model set (``gsa adapt`` run by the service), its operator's own; version 0,
    the configured set (GSA_MODEL_DIR), has no row. Which version answers whom is a ``ModelPromotion``."""

    __tablename__ = "model_versions"
    __table_args__ = (UniqueConstraint("target", "version", name="uq_model_versions_target_version"),)

    id: Mapped[str] = mapped_column(String(36), primary_key=True, default=new_id)
    target: Mapped[str] = mapped_column(String(200), index=True)
    version: Mapped[int] = mapped_column(Integer)
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)
    operator_id: Mapped[str | None] = mapped_column(ForeignKey("operators.id", ondelete="SET NULL"), nullable=True)
    base_version: Mapped[int] = mapped_column(Integer)
    dir: Mapped[str] = mapped_column(String(500))
    summary: Mapped[dict[str, Any]] = mapped_column(JSON)


SHARED_SCOPE = "shared"  # a ModelPromotion's scope for every operator without one of its own


class ModelPromotion(Base):
    """The version that answers a target for one operator (``scope`` its id), or for every operator without a
    promotion of its own (``scope`` "shared", set by an admin key). No row: version 0, the configured set."""

    __tablename__ = "model_promotions"

    scope: Mapped[str] = mapped_column(String(36), primary_key=True)
    target: Mapped[str] = mapped_column(String(200), primary_key=True)
    version: Mapped[int] = mapped_column(Integer)
    promoted_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)
    promoted_by: Mapped[str | None] = mapped_column(String(36), nullable=True)


JOB_ACTIVE = ("queued", "running")
JOB_FINAL = ("done", "failed", "cancelled")


class Job(Base):
    """Long work (``/v1/jobs``): an adaptation, a data set, a campaign... its state, stage, progress and log.

    ``key`` names what must not run twice at once (``adaptation:TARGET``): one active job per key, enforced by a
    partial unique index, so two requests at the same instant cannot both start one. ``runner`` is the
    ``host:pid`` of the worker process running it, ``updated_at`` its last word (a heartbeat).
    """

    __tablename__ = "jobs"
    __table_args__ = (
        Index("ix_jobs_operator_created", "operator_id", "created_at"),
        Index(
            "uq_jobs_active_key",
            "key",
            unique=True,
            sqlite_where=text("state IN ('queued', 'running')"),
            postgresql_where=text("state IN ('queued', 'running')"),
        ),
    )

    id: Mapped[str] = mapped_column(String(36), primary_key=True, default=new_id)
    operator_id: Mapped[str] = mapped_column(ForeignKey("operators.id", ondelete="CASCADE"))
    kind: Mapped[str] = mapped_column(String(32), index=True)
    key: Mapped[str | None] = mapped_column(String(300), nullable=True)
    state: Mapped[str] = mapped_column(String(16), index=True)
    stage: Mapped[str] = mapped_column(String(300), default="")
    progress: Mapped[float] = mapped_column(Float, default=0.0)
    done: Mapped[int] = mapped_column(Integer, default=0)
    total: Mapped[int] = mapped_column(Integer, default=0)
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)
    started_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True), nullable=True)
    updated_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True), nullable=True)
    finished_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True), nullable=True)
    params: Mapped[dict[str, Any]] = mapped_column(JSON)
    result: Mapped[dict[str, Any] | None] = mapped_column(JSON, nullable=True)
    error: Mapped[str | None] = mapped_column(Text, nullable=True)
    log: Mapped[str] = mapped_column(Text, default="")
    runner: Mapped[str] = mapped_column(String(120), default="")
    engine: Mapped[str] = mapped_column(String(16), default="local")
    attempts: Mapped[int] = mapped_column(Integer, default=0)
    cancel_requested: Mapped[bool] = mapped_column(Boolean, default=False)
