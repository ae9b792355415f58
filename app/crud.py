"""Database operations; keyword-only, the session passed in, lookups return None when absent."""

from __future__ import annotations

from datetime import UTC, datetime
from typing import TYPE_CHECKING, Any

from sqlalchemy import delete as sa_delete
from sqlalchemy import func, select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from app.core.security import HMAC_SCHEME, LEGACY_SCHEME, digests_equal, key_digest, key_prefix, new_api_key
from app.db.models import (
    ApiKey,
    Campaign,
    Estimate,
    GroundStation,
    LabelledFrame,
    Operator,
    Pass,
    Plan,
    PlanExport,
    utcnow,
)
from app.schemas.common import name_key

if TYPE_CHECKING:
    from app.schemas import CampaignCreate, CampaignResult, PassResult, PlanCreate, PlanResult


def get_or_create_operator(*, session: Session, name: str) -> Operator:
    """Return the operator called ``name``, creating it if new (safe when several workers race to create it).

    Call it with nothing else pending in the session: losing the race rolls the transaction back.
    """
    op = session.scalar(select(Operator).where(Operator.name == name))
    if op is not None:
        return op
    try:
        op = Operator(name=name)
        session.add(op)
        session.flush()
        return op
    except IntegrityError:  # another worker created it between our read and our insert
        session.rollback()
        op = session.scalar(select(Operator).where(Operator.name == name))
        if op is None:
            raise
        return op


ROLES = ("operator", "admin")  # admin: also the shared default model sets (app.services.model_versions)


def create_api_key(
    *,
    session: Session,
    secret: bytes,
    operator_name: str,
    key_name: str,
    key: str | None = None,
    role: str = "operator",
) -> tuple[ApiKey, str]:
    """Create a key for an operator (created if new); return the row and the plain key (shown once)."""
    if role not in ROLES:
        raise ValueError(f"role {role!r}: one of {', '.join(ROLES)}")
    op = get_or_create_operator(session=session, name=operator_name)
    plain = key or new_api_key()
    row = ApiKey(
        operator_id=op.id,
        name=key_name,
        prefix=key_prefix(plain),
        key_hash=key_digest(plain, secret),
        hash_scheme=HMAC_SCHEME,
        role=role,
    )
    session.add(row)
    session.commit()
    return row, plain


def operator_for_key(*, session: Session, secret: bytes, key: str) -> Operator | None:
    """Return the operator of an active key: rows found by prefix, digests compared in constant time."""
    found = key_for(session=session, secret=secret, key=key)
    return None if found is None else session.get(Operator, found.operator_id)


def key_for(*, session: Session, secret: bytes, key: str) -> ApiKey | None:
    """Return the active stored key ``key`` is: rows found by prefix, digests compared in constant time."""
    rows = session.scalars(select(ApiKey).where(ApiKey.prefix == key_prefix(key), ApiKey.revoked_at.is_(None))).all()
    found = None
    for row in rows:  # every candidate is compared, so the time does not say which one matched
        if digests_equal(key_digest(key, secret, row.hash_scheme), row.key_hash) and found is None:
            found = row
    if found is None:
        return None
    if found.hash_scheme == LEGACY_SCHEME:  # rows from before migration 0003: rewrite as HMAC on first use
        found.key_hash, found.hash_scheme = key_digest(key, secret), HMAC_SCHEME
        session.commit()
    return found


def list_api_keys(*, session: Session) -> list[tuple[ApiKey, Operator]]:
    rows = session.execute(select(ApiKey, Operator).join(Operator).order_by(ApiKey.created_at)).all()
    return [(k, o) for k, o in rows]


def set_key_role(*, session: Session, key_id: str, role: str) -> ApiKey | None:
    """Give key ``key_id`` the role ``role`` (operator or admin); None when there is no such key."""
    if role not in ROLES:
        raise ValueError(f"role {role!r}: one of {', '.join(ROLES)}")
    row = session.get(ApiKey, key_id)
    if row is not None:
        row.role = role
        session.commit()
    return row


def revoke_api_key(*, session: Session, key_id: str) -> ApiKey | None:
    row = session.get(ApiKey, key_id)
    if row is None:
        return None
    if row.revoked_at is None:
        row.revoked_at = utcnow()
        session.commit()
    return row


def count_api_keys(*, session: Session) -> int:
    return int(session.scalar(select(func.count()).select_from(ApiKey)) or 0)


def create_plan(
    *,
    session: Session,
    operator_id: str,
    request: PlanCreate,
    result: PlanResult,
    plan_id: str | None = None,
    exports: dict[str, bytes] | None = None,
) -> Plan:
    """Store a plan: its request as validated (a stored station's copy in it), its typed result and, in the same
    transaction, its exports (name to compressed body) as written when it was made."""
    assert request.ground_station is not None and not isinstance(request.ground_station, str)  # resolved, stored
    chosen = result.chosen
    plan = Plan(
        operator_id=operator_id,
        target_name=request.target.name,
        observer_name=request.observer.name,
        station_name=request.ground_station.name,
        t_access=None if chosen is None else chosen.t_access,
        miss_km=None if chosen is None else chosen.miss_km,
        request=request.model_dump(mode="json"),
        result=result.stored(),
    )
    if plan_id is not None:
        plan.id = plan_id
    session.add(plan)
    session.flush()  # the plan's row first: its exports point at it
    session.add_all(PlanExport(plan_id=plan.id, name=name, body=body) for name, body in (exports or {}).items())
    session.commit()
    return plan


def get_plan_export(*, session: Session, plan_id: str, name: str) -> bytes | None:
    """A plan's stored export (compressed), or None where it has none (a plan made before exports were stored)."""
    return session.scalar(select(PlanExport.body).where(PlanExport.plan_id == plan_id, PlanExport.name == name))


def store_plan_exports(*, session: Session, plan_id: str, exports: dict[str, bytes]) -> None:
    """Keep the exports made for an older plan on its first request (another request storing them first wins)."""
    try:
        session.add_all(PlanExport(plan_id=plan_id, name=name, body=body) for name, body in exports.items())
        session.commit()
    except IntegrityError:
        session.rollback()


def create_campaign(*, session: Session, operator_id: str, request: CampaignCreate, result: CampaignResult) -> Campaign:
    """Store a campaign: its request as validated (a stored station's copy in it) and its typed result."""
    assert request.ground_station is not None and not isinstance(request.ground_station, str)  # resolved, stored
    row = Campaign(
        operator_id=operator_id,
        target_name=request.target.name,
        observer_name=request.observer.name,
        station_name=request.ground_station.name,
        scenes=len(result.scenes),
        dv_total_m_s=result.dv_total_m_s,
        first_access=result.scenes[0].t_access if result.scenes else None,
        request=request.model_dump(mode="json"),
        result=result.stored(),
    )
    session.add(row)
    session.commit()
    return row


def get_campaign(*, session: Session, operator_id: str, campaign_id: str) -> Campaign | None:
    return session.scalar(select(Campaign).where(Campaign.id == campaign_id, Campaign.operator_id == operator_id))


def list_campaigns(
    *, session: Session, operator_id: str, limit: int, offset: int, target_name: str | None = None
) -> tuple[list[Campaign], int]:
    where = [Campaign.operator_id == operator_id]
    if target_name is not None:
        where.append(Campaign.target_name == target_name)
    total = int(session.scalar(select(func.count()).select_from(Campaign).where(*where)) or 0)
    rows = session.scalars(
        select(Campaign).where(*where).order_by(Campaign.created_at.desc(), Campaign.id).limit(limit).offset(offset)
    ).all()
    return list(rows), total


def get_plan(*, session: Session, operator_id: str, plan_id: str) -> Plan | None:
    return session.scalar(select(Plan).where(Plan.id == plan_id, Plan.operator_id == operator_id))


def list_plans(
    *,
    session: Session,
    operator_id: str,
    limit: int,
    offset: int,
    target_name: str | None = None,
    created_after: datetime | None = None,
    created_before: datetime | None = None,
) -> tuple[list[Plan], int]:
    where = [Plan.operator_id == operator_id]
    if target_name is not None:
        where.append(Plan.target_name == target_name)
    if created_after is not None:
        where.append(Plan.created_at >= created_after)
    if created_before is not None:
        where.append(Plan.created_at < created_before)
    total = int(session.scalar(select(func.count()).select_from(Plan).where(*where)) or 0)
    rows = session.scalars(
        select(Plan).where(*where).order_by(Plan.created_at.desc(), Plan.id).limit(limit).offset(offset)
    ).all()
    return list(rows), total


def list_scenes(
    *, session: Session, operator_id: str, limit: int, offset: int
) -> tuple[list[Plan], dict[str, list[Estimate]], int]:
    """A page of the operator's plans, newest first, with each plan's estimates (one query for the page's)."""
    where = Plan.operator_id == operator_id
    total = int(session.scalar(select(func.count()).select_from(Plan).where(where)) or 0)
    plans = list(
        session.scalars(select(Plan).where(where).order_by(Plan.created_at.desc()).limit(limit).offset(offset)).all()
    )
    by_plan: dict[str, list[Estimate]] = {p.id: [] for p in plans}
    if by_plan:
        for e in session.scalars(
            select(Estimate)
            .where(Estimate.plan_id.in_(list(by_plan)), Estimate.operator_id == operator_id)
            .order_by(Estimate.created_at, Estimate.id)
        ):
            by_plan[str(e.plan_id)].append(e)
    return plans, by_plan, total


def create_estimates(*, session: Session, rows: list[Estimate]) -> list[Estimate]:
    """Store several estimates in one transaction (all or none)."""
    session.add_all(rows)
    session.commit()
    return rows


def get_estimate(*, session: Session, operator_id: str, estimate_id: str) -> Estimate | None:
    return session.scalar(select(Estimate).where(Estimate.id == estimate_id, Estimate.operator_id == operator_id))


def list_estimates(
    *,
    session: Session,
    operator_id: str,
    limit: int,
    offset: int,
    plan_id: str | None = None,
    created_after: datetime | None = None,
    created_before: datetime | None = None,
) -> tuple[list[Estimate], int]:
    where = [Estimate.operator_id == operator_id]
    if plan_id is not None:
        where.append(Estimate.plan_id == plan_id)
    if created_after is not None:
        where.append(Estimate.created_at >= created_after)
    if created_before is not None:
        where.append(Estimate.created_at < created_before)
    total = int(session.scalar(select(func.count()).select_from(Estimate).where(*where)) or 0)
    rows = session.scalars(
        select(Estimate).where(*where).order_by(Estimate.created_at.desc(), Estimate.id).limit(limit).offset(offset)
    ).all()
    return list(rows), total


def delete_estimate(*, session: Session, estimate: Estimate) -> None:
    session.delete(estimate)
    session.commit()


def blob_digests(*, session: Session) -> set[str]:
    """Every image digest any estimate refers to (all operators)."""
    used: set[str] = set()
    for original, enhanced in session.execute(select(Estimate.original_sha256, Estimate.enhanced_sha256)):
        used.update((original, enhanced))
    used.update(session.scalars(select(LabelledFrame.frame_sha256)))
    return used


def blob_in_use(*, session: Session, digest: str) -> bool:
    hit = session.scalar(
        select(func.count())
        .select_from(Estimate)
        .where((Estimate.original_sha256 == digest) | (Estimate.enhanced_sha256 == digest))
    )
    labelled = session.scalar(
        select(func.count()).select_from(LabelledFrame).where(LabelledFrame.frame_sha256 == digest)
    )
    return bool(hit) or bool(labelled)


def create_pass(*, session: Session, operator_id: str, plan_id: str, result: PassResult) -> Pass:
    """Store a fused pass (its typed result with its format version) under the plan it belongs to."""
    row = Pass(operator_id=operator_id, created_at=utcnow(), plan_id=plan_id, result=result.stored())
    session.add(row)
    session.commit()
    return row


def get_pass(*, session: Session, operator_id: str, pass_id: str) -> Pass | None:
    return session.scalar(select(Pass).where(Pass.id == pass_id, Pass.operator_id == operator_id))


def tied_to_plan(*, session: Session, operator_id: str, plan_id: str) -> tuple[list[str], list[str]]:
    """The ids of the operator's estimates and passes tied to a plan, oldest first."""
    estimates = session.scalars(
        select(Estimate.id)
        .where(Estimate.operator_id == operator_id, Estimate.plan_id == plan_id)
        .order_by(Estimate.created_at, Estimate.id)
    ).all()
    passes = session.scalars(
        select(Pass.id)
        .where(Pass.operator_id == operator_id, Pass.plan_id == plan_id)
        .order_by(Pass.created_at, Pass.id)
    ).all()
    return list(estimates), list(passes)


def passes_over(*, session: Session, operator_id: str, plan_id: str | None, moment: datetime | None) -> list[str]:
    """The ids of the operator's fused passes of a plan whose frames span ``moment`` (first to last frame's
    ``observed_at``): the pass a frame observed then belongs to, oldest first. None without a plan or a moment."""
    if plan_id is None or moment is None:
        return []
    moment = moment if moment.tzinfo else moment.replace(tzinfo=UTC)  # SQLite gives its times back naive
    rows = session.execute(
        select(Pass.id, Pass.result)
        .where(Pass.operator_id == operator_id, Pass.plan_id == plan_id)
        .order_by(Pass.created_at, Pass.id)
    ).all()
    out = []
    for pass_id, result in rows:
        times = [datetime.fromisoformat(f["observed_at"]) for f in (result or {}).get("frames", [])]
        if times and min(times) <= moment <= max(times):
            out.append(pass_id)
    return out


def list_passes(
    *, session: Session, operator_id: str, limit: int, offset: int, plan_id: str | None = None
) -> tuple[list[Pass], int]:
    where = [Pass.operator_id == operator_id]
    if plan_id is not None:
        where.append(Pass.plan_id == plan_id)
    total = int(session.scalar(select(func.count()).select_from(Pass).where(*where)) or 0)
    rows = session.scalars(
        select(Pass).where(*where).order_by(Pass.created_at.desc(), Pass.id).limit(limit).offset(offset)
    ).all()
    return list(rows), total


def create_station(*, session: Session, operator_id: str, station: dict[str, Any]) -> GroundStation | None:
    """Store a named station; None where the operator already has one of that name, compared by ``name_key``
    (nothing changes)."""
    row = GroundStation(
        operator_id=operator_id, name=station["name"], name_key=name_key(station["name"]), station=station
    )
    session.add(row)
    try:
        session.commit()
    except IntegrityError:
        session.rollback()
        return None
    return row


def get_station(*, session: Session, operator_id: str, name: str) -> GroundStation | None:
    """The operator's station of this name, compared by ``name_key`` (case, width, surrounding spaces aside)."""
    try:
        key = name_key(name)
    except ValueError:
        return None  # no stored name holds what normalising refuses
    return session.scalar(
        select(GroundStation).where(GroundStation.operator_id == operator_id, GroundStation.name_key == key)
    )


def list_stations(*, session: Session, operator_id: str, limit: int, offset: int) -> tuple[list[GroundStation], int]:
    where = GroundStation.operator_id == operator_id
    total = int(session.scalar(select(func.count()).select_from(GroundStation).where(where)) or 0)
    rows = session.scalars(
        select(GroundStation).where(where).order_by(GroundStation.name).limit(limit).offset(offset)
    ).all()
    return list(rows), total


def delete_station(*, session: Session, station: GroundStation) -> bool:
    """Delete the station; False where another request deleted it first (so exactly one DELETE answers 204)."""
    gone = session.execute(sa_delete(GroundStation).where(GroundStation.id == station.id))
    session.commit()
    return bool(getattr(gone, "rowcount", 0))


def labelled_inputs(*, session: Session, operator_id: str, target: str, digests: list[str]) -> set[str]:
    """Which of these uploaded files' digests the operator already stored as labelled frames of ``target``."""
    if not digests:
        return set()
    rows = session.scalars(
        select(LabelledFrame.input_sha256).where(
            LabelledFrame.operator_id == operator_id,
            LabelledFrame.target == target,
            LabelledFrame.input_sha256.in_(digests),
        )
    )
    return set(rows)


def labelled_targets_of_plan(*, session: Session, operator_id: str, plan_id: str) -> set[str]:
    """The targets whose labelled frames the operator placed by this plan."""
    rows = session.scalars(
        select(LabelledFrame.target)
        .where(LabelledFrame.operator_id == operator_id, LabelledFrame.plan_id == plan_id)
        .distinct()
    )
    return set(rows)


def create_labelled(*, session: Session, rows: list[LabelledFrame]) -> list[LabelledFrame]:
    """Store labelled frames together (all or none); a file another request stored meanwhile is a Conflict."""
    from sqlalchemy.exc import IntegrityError

    from app.errors import Conflict

    session.add_all(rows)
    try:
        session.commit()
    except IntegrityError:
        session.rollback()
        raise Conflict("a file of this upload was stored by another request meanwhile; send the upload again") from None
    for r in rows:
        session.refresh(r)
    return rows


def list_labelled(
    *, session: Session, operator_id: str, target: str, limit: int, offset: int, scene: str | None = None
) -> tuple[list[LabelledFrame], int]:
    where = [LabelledFrame.operator_id == operator_id, LabelledFrame.target == target]
    if scene is not None:
        where.append(LabelledFrame.scene == scene)
    total = int(session.scalar(select(func.count()).select_from(LabelledFrame).where(*where)) or 0)
    rows = session.scalars(
        select(LabelledFrame)
        .where(*where)
        .order_by(LabelledFrame.created_at.desc(), LabelledFrame.id)
        .limit(limit)
        .offset(offset)
    ).all()
    return list(rows), total


def delete_labelled(*, session: Session, operator_id: str, target: str, scene: str | None) -> list[str]:
    """Delete the operator's labelled frames of ``target`` (of ``scene`` only, where given); return their images'
    digests (the caller removes those no other row refers to)."""
    where = [LabelledFrame.operator_id == operator_id, LabelledFrame.target == target]
    if scene is not None:
        where.append(LabelledFrame.scene == scene)
    digests = list(session.scalars(select(LabelledFrame.frame_sha256).where(*where)))
    session.execute(sa_delete(LabelledFrame).where(*where))
    session.commit()
    return digests


def labelled_summary(*, session: Session, operator_id: str, target: str) -> tuple[dict[str, int], list[list[float]]]:
    """Counts per scene and every label's angles, for the operator's labelled frames of ``target``."""
    per_scene: dict[str, int] = {}
    angles: list[list[float]] = []
    for scene, a in session.execute(
        select(LabelledFrame.scene, LabelledFrame.angles_deg).where(
            LabelledFrame.operator_id == operator_id, LabelledFrame.target == target
        )
    ):
        per_scene[scene] = per_scene.get(scene, 0) + 1
        angles.append(list(a))
    return per_scene, angles
