"""What every schema shares: the base models, ISO time and text types, and the error bodies."""

from __future__ import annotations

import math
import re
import unicodedata
from datetime import datetime
from typing import TYPE_CHECKING, Annotated, Any, overload

from pydantic import AfterValidator, BaseModel, BeforeValidator, ConfigDict, Field, model_validator

from planner.propagation import as_utc

if TYPE_CHECKING:
    pass

_ISO_DATE = re.compile(r"^\d{4}-\d{2}-\d{2}")


def _iso_only(value: Any) -> Any:
    """Take date-times as ISO 8601 text only: a bare number (``0``, ``1.7e9``) is refused, not read as Unix time."""
    if isinstance(value, str) and not _ISO_DATE.match(value.strip()):
        raise ValueError("give an ISO 8601 date-time such as 2022-11-28T11:28:29Z")
    if isinstance(value, int | float):
        raise ValueError("give an ISO 8601 date-time such as 2022-11-28T11:28:29Z, not a number")
    return value


@overload
def utc_or_none(moment: datetime) -> datetime: ...
@overload
def utc_or_none(moment: None) -> None: ...
def utc_or_none(moment: datetime | None) -> datetime | None:
    """The same instant as aware UTC (planner.propagation.as_utc; naive is taken as UTC), or None.

    SQLite hands back naive datetimes for UTC columns, and a filter given with another offset
    (``+14:00``) must be the same instant in UTC before it is compared (SQLite compares the text).
    """
    return None if moment is None else as_utc(moment)


def _as_utc_in_range(moment: datetime) -> datetime:
    """The same instant in UTC; one that UTC cannot hold (0001-01-01T00:00+14:00) is a 422, not a crash."""
    try:
        return as_utc(moment)
    except OverflowError:
        raise ValueError("this date-time falls outside years 1-9999 once in UTC; give a real epoch") from None


IsoDateTime = Annotated[datetime, BeforeValidator(_iso_only), AfterValidator(_as_utc_in_range)]

CONTROL_CHARACTERS = re.compile(r"[\x00-\x1f\x7f]")
# A lone UTF-16 surrogate ("\ud800" in JSON) is no character: no database stores it, no answer can echo it.
SURROGATES = re.compile(r"[\ud800-\udfff]")
SURROGATE_MESSAGE = (
    "holds a lone UTF-16 surrogate (an escape like \\ud800 that is half a character); send valid Unicode"
)


def _no_control(value: str | None) -> str | None:
    if value is not None and CONTROL_CHARACTERS.search(value):
        raise ValueError("must not contain control characters (NUL, tab, newline, ...); remove them")
    if value is not None and SURROGATES.search(value):
        raise ValueError(SURROGATE_MESSAGE)
    return value


def surrogate_path(value: Any, path: tuple[str | int, ...] = ()) -> tuple[str | int, ...] | None:
    """Where in a JSON value a string (or a key) holds a lone surrogate, or None."""
    if isinstance(value, str):
        return path if SURROGATES.search(value) else None
    if isinstance(value, dict):
        for k, v in value.items():
            if isinstance(k, str) and SURROGATES.search(k):
                return (*path, k)
            found = surrogate_path(v, (*path, k))
            if found is not None:
                return found
    if isinstance(value, list | tuple):
        for i, v in enumerate(value):
            found = surrogate_path(v, (*path, i))
            if found is not None:
                return found
    return None


# An id, filter or name from a path, a query or a form: NUL and other control characters are
# refused at the edge (PostgreSQL cannot store NUL in text, and no id or name holds one).
Text = Annotated[str, AfterValidator(_no_control)]


def normalise_name(value: str) -> str:
    """A name as stored: Unicode NFC, surrounding spaces trimmed; control, format (zero-width, bidi) and
    separator characters refused, and the path segments "." and "..". Names differing only in case or width
    are one name (``name_key``)."""
    name = unicodedata.normalize("NFC", value).strip()
    bad = next((c for c in name if unicodedata.category(c) in ("Cc", "Cf", "Cs", "Co", "Cn", "Zl", "Zp")), None)
    if bad is not None:
        raise ValueError(
            f"must not contain control, invisible or unassigned characters (U+{ord(bad):04X} "
            f"{unicodedata.name(bad, 'unnamed')}); remove it"
        )
    if not name:
        raise ValueError("must hold a visible character")
    if name in (".", ".."):
        raise ValueError(f"{name!r} is a path segment, not a name (it could not be read or deleted by its URL)")
    return name


def name_key(name: str) -> str:
    """What two names are compared by: NFKC (full-width and other compatibility forms folded) and case folded.

    "GS", "gs", "GS " and "\uff27\uff33" (full width) are one station."""
    return unicodedata.normalize("NFKC", normalise_name(name)).casefold()


Name = Annotated[
    str, Field(min_length=1, max_length=200, pattern=r"^[^/\\\x00-\x1f]+$"), AfterValidator(normalise_name)
]
Finite = Annotated[float, Field(allow_inf_nan=False)]


def finite_or_null(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


class Described(BaseModel):
    """Every field's description is the docstring under it (or its Field's): one place for each field's words."""

    model_config = ConfigDict(use_attribute_docstrings=True)


STORED_FORMAT = 2  # a stored result's shape: 1 before rows wrote "format" (read by each result's _from_format), 2 since


class StoredResult(Described):
    """A result the database keeps as JSON with its format version, and reads back whatever row's format."""

    def stored(self) -> dict[str, Any]:
        """The JSON the database keeps: this result with its format version."""
        return {"format": STORED_FORMAT, **self.model_dump(mode="json")}

    @classmethod
    def upgraded(cls, stored: dict[str, Any]) -> dict[str, Any]:
        """A stored result of any format as the current shape's fields (without ``format``)."""
        out = dict(stored)
        cls._from_format(out.pop("format", 1), out)
        return out

    @classmethod
    def _from_format(cls, version: int, fields: dict[str, Any]) -> None:
        """Bring a stored result of an older ``version`` to the current fields, in place (format 1 of plans and
        passes holds the same fields, their times with +00:00 instead of Z: nothing to do)."""


class Strict(Described):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    @model_validator(mode="before")
    @classmethod
    def _valid_unicode(cls, data: Any) -> Any:
        where = surrogate_path(data)
        if where is not None:
            raise ValueError(f"{'.'.join(str(p) for p in where) or 'the text'} {SURROGATE_MESSAGE}")
        return data


class ErrorMessage(Described):
    """An error that is not about one field: its reason and the request id to quote."""

    detail: str
    """what was wrong and what to do"""
    request_id: str | None = None
    """the X-Request-ID of the request, to find it in the server's log"""


ERROR_RESPONSES: dict[int | str, dict[str, Any]] = {
    400: {"model": ErrorMessage, "description": "the body could not be parsed"},
    401: {"model": ErrorMessage, "description": "no API key, or an invalid or revoked one"},
    413: {"model": ErrorMessage, "description": "the request or an uploaded file is over its size limit"},
}
