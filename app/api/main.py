from fastapi import APIRouter, Depends, Request
from fastapi.dependencies.models import Dependant
from fastapi.routing import APIRoute

from app.api.deps import CurrentOperator
from app.api.routes import (
    access,
    campaigns,
    datasets,
    estimates,
    jobs,
    model_sets,
    passes,
    plans,
    scenes,
    stations,
    targets,
)
from app.errors import InputError
from app.schemas import ERROR_RESPONSES


def _query_names(dep: Dependant) -> set[str]:
    names = {p.alias for p in dep.query_params}
    for sub in dep.dependencies:
        names |= _query_names(sub)
    return names


def _form_names(dep: Dependant) -> set[str]:
    """Every form field a route takes, its dependencies' included (the estimate routes share theirs)."""
    names = {p.alias for p in dep.body_params}
    for sub in dep.dependencies:
        names |= _form_names(sub)
    return names


def reject_unknown_query(request: Request, _operator: CurrentOperator) -> None:
    """Refuse query parameters a route does not take: a misspelt filter must not silently list everything.

    Authentication comes first (a caller without a key learns nothing about the routes' parameters).
    """
    route = request.scope.get("route")
    if not isinstance(route, APIRoute) or not request.query_params:
        return
    allowed = _query_names(route.dependant)
    unknown = sorted(set(request.query_params.keys()) - allowed)
    if unknown:
        takes = ", ".join(sorted(allowed)) or "none"
        raise InputError(
            [unknown[0]], f"unknown query parameter {unknown[0]!r}; this route takes: {takes}", where="query"
        )


async def reject_unknown_form_fields(request: Request, _operator: CurrentOperator) -> None:
    """Refuse form fields a route does not take: a misspelt ``plan_id`` must not be silently ignored."""
    route = request.scope.get("route")
    if not isinstance(route, APIRoute) or not request.headers.get("content-type", "").startswith("multipart/"):
        return
    allowed = _form_names(route.dependant)
    unknown = sorted(set((await request.form()).keys()) - allowed)
    if unknown:
        raise InputError(
            [unknown[0][:100]],
            f"unknown form field {unknown[0][:100]!r}; this route takes: {', '.join(sorted(allowed))}",
        )


async def reject_invalid_unicode(request: Request, _operator: CurrentOperator) -> None:
    """Refuse a JSON body whose text holds a lone UTF-16 surrogate (``"\\ud800"``), naming where, before any model
    reads it: no database stores one and no answer can echo it (it was a 500)."""
    import json

    from app.schemas.common import SURROGATE_MESSAGE, surrogate_path

    if not request.headers.get("content-type", "").startswith("application/json"):
        return
    try:
        body = json.loads(await request.body())
    except ValueError:
        return  # not JSON: the route's own validation says so
    where = surrogate_path(body)
    if where is not None:
        raise InputError(list(where), f"{'.'.join(str(p) for p in where) or 'the body'} {SURROGATE_MESSAGE}")


api_router = APIRouter(
    responses=ERROR_RESPONSES,
    dependencies=[
        Depends(reject_unknown_query),
        Depends(reject_unknown_form_fields),
        Depends(reject_invalid_unicode),
    ],
)
api_router.include_router(plans.router)
api_router.include_router(campaigns.router)
api_router.include_router(access.router)
api_router.include_router(estimates.router)
api_router.include_router(scenes.router)
api_router.include_router(passes.router)
api_router.include_router(stations.router)
api_router.include_router(targets.router)
api_router.include_router(model_sets.router)
api_router.include_router(jobs.router)
api_router.include_router(datasets.router)
