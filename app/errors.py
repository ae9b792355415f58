"""Map domain errors to HTTP in one place: bad input is a 422 that names the field."""

from __future__ import annotations

from typing import Any

from fastapi import FastAPI, Request
from fastapi.responses import JSONResponse

from planner.errors import PlannerError


class InputError(ValueError):
    """A request that passed the schema but that the planner cannot use; ``loc`` is the JSON path."""

    def __init__(self, loc: list[str | int], message: str) -> None:
        super().__init__(message)
        self.loc = loc
        self.message = message


def _body(loc: list[Any], msg: str) -> dict[str, Any]:
    return {"detail": [{"loc": loc, "msg": msg, "type": "value_error"}]}


def install_error_handlers(app: FastAPI) -> None:
    @app.exception_handler(InputError)
    async def _input_error(_request: Request, exc: InputError) -> JSONResponse:
        return JSONResponse(status_code=422, content=_body(["body", *exc.loc], exc.message))

    @app.exception_handler(PlannerError)
    async def _planner_error(_request: Request, exc: PlannerError) -> JSONResponse:
        return JSONResponse(status_code=422, content=_body(["body", exc.field or "request"], str(exc)))
