"""Model sets: each target's versions, adaptations that make new ones from the caller's labelled frames, promotion."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Body, HTTPException, Query, Request
from fastapi import Path as PathParam
from fastapi.responses import JSONResponse, Response

from app.api.deps import (
    CheckersDep,
    CurrentOperator,
    ModelSetsDep,
    SessionDep,
    SettingsDep,
    checker_for,
    is_admin,
    queued,
)
from app.schemas import (
    AdaptationCreate,
    AdaptationPublic,
    JobPublic,
    ModelSetPublic,
    ModelSetsPublic,
    ModelVersionPublic,
    ReestimationCreate,
    Text,
)
from app.services import jobs as jobs_svc
from app.services import model_versions as mv
from app.services.reestimation import submit_reestimation

router = APIRouter(prefix="/model-sets", tags=["model sets"])


def _set_of(session: Any, model_sets: Any, target: str, operator_id: str, admin: bool) -> ModelSetPublic:
    """The target's set as ``operator_id`` sees it: version 0, its own versions and the shared default (an admin
    key: every version); never another operator's details or a server path."""
    answering = mv.answering_version(session, operator_id, target)
    shared = mv.shared_version(session, target)
    base = ModelVersionPublic(
        version=0, promoted=answering == 0, shared_default=shared == 0, summary=model_sets.for_target(target).identity
    )
    rows = mv.visible(session, operator_id, target, admin)
    listed = [
        ModelVersionPublic.from_row(r, answering=answering, shared=shared, operator_id=operator_id, admin=admin)
        for r in rows
    ]
    return ModelSetPublic(target=target, answering_version=answering, shared_version=shared, versions=[base, *listed])


@router.get("", response_model=ModelSetsPublic)
def list_model_sets(
    request: Request, session: SessionDep, operator: CurrentOperator, model_sets: ModelSetsDep
) -> ModelSetsPublic:
    """Every target's model set as it answers you: the versions you may see (0, the configured set; your own
    adaptations; the shared default), which one answers you and which one answers everyone else."""
    admin = is_admin(request)
    return ModelSetsPublic(data=[_set_of(session, model_sets, t, operator.id, admin) for t in model_sets.sets])


def _trained_target(checkers: Any, model_sets: Any, target: str) -> str:
    name = str(checker_for(checkers, target).model.name)
    if name not in model_sets.sets:
        from app.errors import InputError

        raise InputError(
            ["target"],
            f"no model set is trained on {name!r} (the service's sets: {', '.join(model_sets.sets)}); adapt a set "
            "trained on the target the frames show",
            where="path",
        )
    return name


@router.post(
    "/{target}/adaptations",
    status_code=202,
    response_model=AdaptationPublic,
    responses={409: {"description": "an adaptation of this target is already queued or running"}},
)
def create_adaptation(
    request: Request,
    session: SessionDep,
    operator: CurrentOperator,
    settings: SettingsDep,
    model_sets: ModelSetsDep,
    checkers: CheckersDep,
    target: Annotated[Text, PathParam(max_length=200, description="the target whose set to adapt")],
    body: Annotated[AdaptationCreate | None, Body()] = None,
) -> AdaptationPublic:
    """Adapt the target's answering set to the caller's labelled frames of it, in the background: a new version,
    not promoted. ``GET .../adaptations/{id}`` follows it; a failure leaves the served set unchanged."""
    name = _trained_target(checkers, model_sets, target)
    job = mv.start(
        session=session,
        settings=settings,
        operator_id=operator.id,
        target=name,
        base_dir=model_sets.for_target(name).model_dir,
        options=(body or AdaptationCreate()).model_dump(exclude_none=True),
    )
    request.app.state.jobs.nudge()
    return AdaptationPublic.from_row(job)


@router.get(
    "/{target}/adaptations/{adaptation_id}",
    response_model=AdaptationPublic,
    responses={404: {"description": "no adaptation with this id is yours"}},
)
def read_adaptation(
    session: SessionDep,
    operator: CurrentOperator,
    target: Annotated[Text, PathParam(max_length=200)],
    adaptation_id: Annotated[Text, PathParam(max_length=36)],
) -> AdaptationPublic:
    """One of the caller's adaptations: state, stage, progress, log, and the version it made."""
    job = jobs_svc.own(session, operator.id, adaptation_id)
    if job is None or job.kind != "adaptation" or job.params.get("target") != target:
        raise HTTPException(status_code=404, detail="Adaptation not found")
    return AdaptationPublic.from_row(job)


@router.post(
    "/{target}/re-estimations",
    status_code=202,
    response_model=JobPublic,
    responses={202: {"description": "queued: follow it at /v1/jobs/{id}"}},
)
def create_reestimation(
    request: Request,
    session: SessionDep,
    operator: CurrentOperator,
    settings: SettingsDep,
    model_sets: ModelSetsDep,
    checkers: CheckersDep,
    target: Annotated[Text, PathParam(max_length=200, description="the target whose estimates to read again")],
    body: ReestimationCreate,
) -> JSONResponse:
    """Read the caller's stored estimates of the target again with another version of its set, as a job: each
    gets a new estimate (same plan, time and name, "re-estimate of ..."); the job's result says how far each
    answer moved and how many are trusted before and after. The old estimates stay."""
    name = _trained_target(checkers, model_sets, target)
    job = submit_reestimation(
        session=session,
        settings=settings,
        operator_id=operator.id,
        target=name,
        version=body.version,
        plan_id=body.plan_id,
        limit=body.limit,
    )
    return queued(request, job)


@router.post(
    "/{target}/versions/{version}/promote",
    response_model=ModelSetPublic,
    responses={
        403: {"description": "shared=true without an admin key"},
        404: {"description": "the target's set has no such version of yours"},
        409: {"description": "the version failed the quality gate (its files, a smoke estimate); the reason is given"},
    },
)
def promote_version(
    request: Request,
    session: SessionDep,
    operator: CurrentOperator,
    model_sets: ModelSetsDep,
    checkers: CheckersDep,
    target: Annotated[Text, PathParam(max_length=200)],
    version: Annotated[int, PathParam(ge=0, le=100_000, description="the version; 0 withdraws the promotion")],
    shared: Annotated[
        bool, Query(description="promote it as the shared default, for every operator without its own (admin keys)")
    ] = False,
) -> ModelSetPublic:
    """Make ``version`` answer the target for you from the next request on (every worker reads it from the
    database): one of your own versions, or the shared default; 0 withdraws your promotion, so the shared default
    answers you again. With ``shared=true`` an admin key sets the shared default instead (0: the configured set).
    The version must first pass the quality gate: its files load and verify, and a smoke estimate runs."""
    name = _trained_target(checkers, model_sets, target)
    admin = is_admin(request)
    try:
        mv.promote_checked(
            session,
            request.app.state.served,
            checker_for(checkers, name),
            operator_id=operator.id,
            target=name,
            version=version,
            shared=shared,
            admin=admin,
        )
    except LookupError:
        raise HTTPException(status_code=404, detail=f"{name} has no version {version} of yours") from None
    return _set_of(session, model_sets, name, operator.id, admin)


@router.delete(
    "/{target}/versions/{version}",
    status_code=204,
    responses={
        404: {"description": "the target's set has no such version of yours"},
        409: {"description": "the version is promoted (or the shared default, or version 0): it answers someone"},
    },
)
def delete_version(
    session: SessionDep,
    operator: CurrentOperator,
    settings: SettingsDep,
    model_sets: ModelSetsDep,
    checkers: CheckersDep,
    target: Annotated[Text, PathParam(max_length=200)],
    version: Annotated[int, PathParam(ge=0, le=100_000, description="one of your versions, not promoted")],
) -> Response:
    """Delete one of your adapted versions and its files, once nothing answers with it (promote another first)."""
    name = _trained_target(checkers, model_sets, target)
    try:
        mv.delete_version(session, settings, operator_id=operator.id, target=name, version=version)
    except LookupError:
        raise HTTPException(status_code=404, detail=f"{name} has no version {version} of yours") from None
    return Response(status_code=204)
