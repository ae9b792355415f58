"""CCSDS navigation messages in KVN (502.0-B-3), as inputs: an OMM's mean elements and an OPM's state vector.

KVN is one ``KEYWORD = value [units]`` a line, ``COMMENT`` lines and blank lines ignored, each
message opened by its version keyword (``CCSDS_OMM_VERS``, ``CCSDS_OPM_VERS``). The OMM's fields
go on to sgp4's own OMM record (``planner.tle.tle_from_omm``); the OPM's state vector becomes the
osculating elements the planner propagates.
"""

from __future__ import annotations

import calendar
import math
import re
from datetime import UTC, datetime, timedelta

from planner.constants import MU_EARTH_KM3_S2
from planner.elements import Elements, elements_of_state
from planner.errors import ElementsError, TLEError

VERSIONS = ("2.0", "3.0")
_UNITS = re.compile(r"\s*\[[^\]]*\]\s*$")
# Inertial frames whose axes are the planner's GCRS ones to within EME2000's 23-mas frame bias.
INERTIAL_FRAMES = ("EME2000", "GCRF", "ICRF")
STATE_KEYS = ("X", "Y", "Z", "X_DOT", "Y_DOT", "Z_DOT")


def parse_kvn(text: str, version_key: str, field: str) -> list[dict[str, str]]:
    """The messages of a KVN text, each a dict of keyword to value (units dropped), checked for their version."""
    error = TLEError if version_key == "CCSDS_OMM_VERS" else ElementsError
    messages: list[dict[str, str]] = []
    for n, raw in enumerate(text.splitlines(), 1):
        line = raw.strip()
        if not line or line.startswith("COMMENT"):
            continue
        if "=" not in line:
            raise error(f"line {n} is not KEYWORD = value: {line[:60]!r}", field=field)
        key, value = (part.strip() for part in line.split("=", 1))
        value = _UNITS.sub("", value)
        if key == version_key:
            if value not in VERSIONS:
                raise error(f"{version_key} {value!r}: this reads versions 2.0 and 3.0", field=version_key)
            messages.append({})
        elif not messages:
            raise error(f"a message starts with {version_key} = 3.0 (or 2.0); line {n} comes first", field=field)
        messages[-1][key] = value
    if len(messages) != 1:
        raise error(f"the text holds {len(messages)} messages; send one", field=field)
    return messages


def omm_fields_from_kvn(text: str) -> dict[str, object]:
    """The one OMM of a KVN text (CelesTrak's ``FORMAT=kvn``) as the field dict ``tle_from_omm`` reads."""
    return dict(parse_kvn(text, "CCSDS_OMM_VERS", "omm_kvn")[0])


def _number(fields: dict[str, str], key: str) -> float:
    if key not in fields:
        raise ElementsError(f"the OPM has no {key}", field=key)
    try:
        value = float(fields[key])
    except ValueError:
        raise ElementsError(f"{key} {fields[key]!r} is not a number", field=key) from None
    if not math.isfinite(value):
        raise ElementsError(f"{key} must be finite", field=key)
    return value


_DOY = re.compile(r"^(\d{4})-(\d{3})T(\d{2}):(\d{2}):(\d{2}(?:\.\d+)?)Z?$")


def ccsds_time(text: str) -> datetime:
    """A CCSDS time (502.0-B-3 / 301.0-B-4 ASCII time code A or B): ``YYYY-MM-DDThh:mm:ss[.d...]`` or the day of
    year, ``YYYY-DDDThh:mm:ss[.d...]``, with or without a trailing Z; UTC. Raises ValueError.

    >>> ccsds_time("2022-331T16:00:00").isoformat()
    '2022-11-27T16:00:00+00:00'
    """
    text = text.strip()
    m = _DOY.match(text)
    if m:
        year, day, hour, minute, second = m.groups()
        if not 1 <= int(day) <= (366 if calendar.isleap(int(year)) else 365):
            raise ValueError(f"day of year {day} does not exist in {year}")
        whole = float(second)
        start = datetime(int(year), 1, 1, int(hour), int(minute), tzinfo=UTC)
        return start + timedelta(days=int(day) - 1, seconds=whole)
    return datetime.fromisoformat(text.rstrip("Z")).replace(tzinfo=UTC)


def elements_from_opm(text: str) -> Elements:
    """The osculating elements of an OPM's state vector (km, km/s; Earth-centred, inertial, UTC)."""
    fields = parse_kvn(text, "CCSDS_OPM_VERS", "opm")[0]
    for key, allowed in (("CENTER_NAME", ("EARTH",)), ("REF_FRAME", INERTIAL_FRAMES), ("TIME_SYSTEM", ("UTC",))):
        got = fields.get(key, "").upper()
        if got not in allowed:
            raise ElementsError(f"{key} {got or 'missing'}: give {' or '.join(allowed)}", field=key)
    try:
        epoch = ccsds_time(fields.get("EPOCH", ""))
    except ValueError:
        raise ElementsError(
            f"EPOCH {fields.get('EPOCH')!r} is not a CCSDS time (YYYY-MM-DDThh:mm:ss or YYYY-DDDThh:mm:ss, UTC)",
            field="EPOCH",
        ) from None
    r = [_number(fields, k) for k in STATE_KEYS[:3]]
    v = [_number(fields, k) for k in STATE_KEYS[3:]]
    energy = 0.5 * sum(x * x for x in v) - MU_EARTH_KM3_S2 / math.sqrt(sum(x * x for x in r))
    if not energy < 0.0:
        raise ElementsError("the state vector is not a bound (elliptic) Earth orbit: check X_DOT..Z_DOT", field="X_DOT")
    return elements_of_state(r, v, epoch)  # Elements validate themselves
