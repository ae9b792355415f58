"""CCSDS navigation data messages (502.0-B-3) read and written with ``ccsds-ndm``: KVN and XML.

Reading: an OPM's state vector becomes the osculating elements the planner propagates; an OMM's mean elements go on
to sgp4's own OMM record (``planner.tle.tle_from_omm``). Writing: the OPM (a state and impulsive manoeuvres) and the
OEM (segments of states) of a plan or a campaign. ``ccsds-ndm`` (the CCSDS NDM/XML 4.0 schemas as data classes,
with its KVN and XML readers and writers) does the syntax of both forms, so what the service writes is what the
standard's tools read and the other way round; this module checks what the planner needs of a message (an Earth-
centred inertial frame, UTC, a bound orbit) and names the keyword at fault.

ccsds-ndm's KVN reader passes over lines it does not know (a misspelt keyword, a line with no ``=``) and reads a
second message in the same text over the first, so a KVN text is first checked here for its shape: one message,
its version keyword first, each line ``KEYWORD = value``.
"""

from __future__ import annotations

import calendar
import dataclasses
import enum
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from planner.constants import MU_EARTH_KM3_S2
from planner.elements import Elements, elements_of_state
from planner.errors import ElementsError, TLEError

Format = Literal["kvn", "xml"]
FORMATS: tuple[Format, ...] = ("kvn", "xml")
VERSIONS = ("2.0", "3.0")
# Inertial frames whose axes are the planner's GCRS ones to within EME2000's 23-mas frame bias.
INERTIAL_FRAMES = ("EME2000", "GCRF", "ICRF")
_KVN_LINE = re.compile(r"^[A-Z][A-Z0-9_]*\s*=")
# An OEM's KVN also holds block markers and data lines (an epoch, then numbers), which are not KEYWORD = value.
_OEM_FREE_LINE = re.compile(r"^((META|COVARIANCE)_(START|STOP)|\d{4}-\d{2,3}[\dT:.\-]*Z?(\s+\S+)+)$")
_XML_VERSION = re.compile(r"<(opm|omm|oem)\b[^>]*\bversion\s*=\s*[\"']([^\"']*)[\"']", re.I)


def ccsds_time_text(t: datetime) -> str:
    """A CCSDS time (ASCII time code A), UTC without a zone designator, to the microsecond (a state written to the
    millisecond belongs to a moment up to 0.5 ms away: 4 m along-track in low orbit)."""
    return t.astimezone(UTC).strftime("%Y-%m-%dT%H:%M:%S.%f")


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
        start = datetime(int(year), 1, 1, int(hour), int(minute), tzinfo=UTC)
        return start + timedelta(days=int(day) - 1, seconds=float(second))
    return datetime.fromisoformat(text.rstrip("Z")).replace(tzinfo=UTC)


# --------------------------------------------------------------------------------------------------- reading


def _check_kvn(text: str, kind: str, error: type[ElementsError] | type[TLEError], field: str) -> None:
    """One KVN message of ``kind`` (OPM, OMM), its version first and readable, every line ``KEYWORD = value``."""
    version_key = f"CCSDS_{kind}_VERS"
    seen = 0
    for n, raw in enumerate(text.splitlines(), 1):
        line = raw.strip()
        if not line or line.startswith("COMMENT"):
            continue
        if kind == "OEM" and _OEM_FREE_LINE.match(line):
            continue
        if not _KVN_LINE.match(line):
            raise error(f"line {n} is not KEYWORD = value: {line[:60]!r}", field=field)
        key, value = (part.strip() for part in line.split("=", 1))
        value = re.sub(r"\s*\[[^\]]*\]\s*$", "", value)
        if key.startswith("CCSDS_") and key.endswith("_VERS") and key != version_key:
            raise error(f"this is a {key[6:9]}, not an {kind}", field=field)
        if key == version_key:
            seen += 1
            if value not in VERSIONS:
                raise error(f"{version_key} {value!r}: this reads versions 2.0 and 3.0", field=version_key)
        elif not seen:
            raise error(f"a message starts with {version_key} = 3.0 (or 2.0); line {n} comes first", field=field)
    if seen != 1:
        raise error(f"the text holds {seen} messages; send one", field=field)


def _check_xml(text: str, kind: str, error: type[ElementsError] | type[TLEError], field: str) -> None:
    if re.search(r"<!(DOCTYPE|ENTITY)", text, re.I):  # NDM/XML needs no DTD: no entity expansion, no external files
        raise error("a DOCTYPE or ENTITY declaration is not read: send the NDM/XML message without one", field=field)
    found = _XML_VERSION.findall(text)
    kinds = {k.upper() for k, _ in found}
    if kinds - {kind}:
        raise error(f"this is a {'/'.join(sorted(kinds))} in XML, not an {kind}", field=field)
    if len(found) != 1:
        raise error(f"the XML holds {len(found)} {kind} messages; send one", field=field)
    if found[0][1] not in VERSIONS:
        raise error(f"CCSDS_{kind}_VERS {found[0][1]!r}: this reads versions 2.0 and 3.0", field=f"CCSDS_{kind}_VERS")


def read_message(text: str, kind: Literal["OPM", "OMM", "OEM"], field: str) -> Any:
    """The one ``kind`` message of a KVN or XML text as ccsds-ndm's data classes (its ``header``, ``body.segment``).
    Raises ElementsError (OPM, OEM) or TLEError (OMM) naming ``field`` or the keyword at fault."""
    from ccsds_ndm.ndm_io import NdmIo

    error = TLEError if kind == "OMM" else ElementsError
    xml = text.lstrip().startswith("<")
    (_check_xml if xml else _check_kvn)(text, kind, error, field)
    try:
        message = NdmIo().from_string(text)
    except Exception as exc:  # the library raises what its parsers do  # noqa: BLE001
        what = str(exc).splitlines()[0][:200] if str(exc) else type(exc).__name__
        raise error(f"not a readable {kind} ({'XML' if xml else 'KVN'}): {what}", field=field) from None
    if type(message).__name__ == "Ndm":  # an <ndm> wrapper (CelesTrak's XML): the one message in it
        inner = list(getattr(message, kind.lower(), []) or [])
        if len(inner) != 1:
            raise error(f"the XML holds {len(inner)} {kind} messages; send one", field=field)
        message = inner[0]
    if type(message).__name__.upper() != kind:
        raise error(f"this is a {type(message).__name__.upper()}, not an {kind}", field=field)
    return message


def fields_of(node: Any, out: dict[str, object] | None = None) -> dict[str, object]:
    """A message part's keywords and values, flattened (``MEAN_MOTION``: 15.72...), as the KVN names them; units
    dropped, enumerations as their text, comments left out."""
    out = {} if out is None else out
    for f in dataclasses.fields(node):
        value = getattr(node, f.name)
        name = f.metadata.get("name", f.name)
        if value is None or isinstance(value, list):
            continue
        if dataclasses.is_dataclass(value):
            if any(g.name == "value" for g in dataclasses.fields(value)):
                out[name] = getattr(value, "value")  # a quantity with units  # noqa: B009
            else:
                fields_of(value, out)
        else:
            out[name] = value.value if isinstance(value, enum.Enum) else value
    return out


def omm_fields(text: str, field: str) -> dict[str, object]:
    """The one OMM of a KVN or XML text (CelesTrak's ``FORMAT=kvn`` or ``xml``) as the field dict ``tle_from_omm``
    reads."""
    segment = read_message(text, "OMM", field).body.segment
    return {**fields_of(segment.metadata), **fields_of(segment.data)}


def _number(fields: dict[str, object], key: str) -> float:
    if fields.get(key) is None:
        raise ElementsError(f"the OPM has no {key}", field=key)
    value = float(fields[key])  # type: ignore[arg-type]
    if not math.isfinite(value):
        raise ElementsError(f"{key} must be finite", field=key)
    return value


def _check_metadata(metadata: Any) -> None:
    """An Earth-centred inertial frame in UTC, or ElementsError naming the keyword."""
    meta = fields_of(metadata)
    for key, allowed in (("CENTER_NAME", ("EARTH",)), ("REF_FRAME", INERTIAL_FRAMES), ("TIME_SYSTEM", ("UTC",))):
        got = str(meta.get(key) or "").upper()
        if got not in allowed:
            raise ElementsError(f"{key} {got or 'missing'}: give {' or '.join(allowed)}", field=key)


def elements_from_opm(text: str, field: str = "opm") -> Elements:
    """The osculating elements of an OPM's state vector (KVN or XML; km, km/s; Earth-centred, inertial, UTC)."""
    segment = read_message(text, "OPM", field).body.segment
    _check_metadata(segment.metadata)
    return _state_elements(segment.data.state_vector)


def _state_elements(state: Any) -> Elements:
    """The osculating elements of one state vector of an OPM or OEM (EPOCH, X..Z_DOT)."""
    values = fields_of(state) if state is not None else {}
    try:
        epoch = ccsds_time(str(values.get("EPOCH", "")))
    except ValueError:
        raise ElementsError(
            f"EPOCH {values.get('EPOCH')!r} is not a CCSDS time (YYYY-MM-DDThh:mm:ss or YYYY-DDDThh:mm:ss, UTC)",
            field="EPOCH",
        ) from None
    r = [_number(values, k) for k in ("X", "Y", "Z")]
    v = [_number(values, k) for k in ("X_DOT", "Y_DOT", "Z_DOT")]
    energy = 0.5 * sum(x * x for x in v) - MU_EARTH_KM3_S2 / math.sqrt(sum(x * x for x in r))
    if not energy < 0.0:
        raise ElementsError("the state vector is not a bound (elliptic) Earth orbit: check X_DOT..Z_DOT", field="X_DOT")
    return elements_of_state(r, v, epoch)  # Elements validate themselves


@dataclass(frozen=True)
class Ephemeris:
    """An OEM read as an orbit input: the osculating elements of its first state, every state of its segments
    (epochs, and positions (3, N) in km) to compare a flight with, and how many segments it holds."""

    elements: Elements
    epochs: tuple[datetime, ...]
    r_km: NDArray[np.float64]
    segments: int


def ephemeris_from_oem(text: str, field: str = "oem") -> Ephemeris:
    """An OEM (KVN or XML; Earth-centred, inertial, UTC): its first segment's first state as osculating elements, and
    that segment's states. Later segments (what follows a manoeuvre, or another object) are counted, not flown."""
    segments = list(read_message(text, "OEM", field).body.segment or [])
    if not segments:
        raise ElementsError("the OEM holds no segment", field=field)
    first = segments[0]
    _check_metadata(first.metadata)
    states = list(getattr(first.data, "state_vector", None) or [])
    if not states:
        raise ElementsError("the OEM's first segment holds no state", field=field)
    elements = _state_elements(states[0])
    epochs, r = [], []
    for sv in states:
        values = fields_of(sv)
        try:
            epochs.append(ccsds_time(str(values.get("EPOCH", ""))))
        except ValueError:
            raise ElementsError(f"EPOCH {values.get('EPOCH')!r} is not a CCSDS time", field="EPOCH") from None
        r.append([_number(values, k) for k in ("X", "Y", "Z")])
    if any(b <= a for a, b in zip(epochs, epochs[1:], strict=False)):
        raise ElementsError("the OEM's first segment's epochs do not increase", field="EPOCH")
    return Ephemeris(elements, tuple(epochs), np.array(r, float).T, len(segments))


def opm_manoeuvre_note(text: str, name: str, field: str = "opm") -> str | None:
    """What an OPM's manoeuvres mean for a plan read from it, or None where it lists none.

    A plan starts from the OPM's state vector and applies none of its manoeuvres (the planner plans its own burns);
    the note says so, so that a burn listed in the message is never dropped unseen.
    """
    segment = read_message(text, "OPM", field).body.segment
    burns = list(getattr(segment.data, "maneuver_parameters", None) or [])
    if not burns:
        return None
    first = str(getattr(burns[0], "man_epoch_ignition", "") or "").strip()
    return (
        f"{name}: the OPM lists {len(burns)} manoeuvre(s) (the first at {first or 'an unstated time'}); the plan "
        "starts from its state vector at EPOCH and applies none of them: to plan from after a burn, send the "
        "state orbit determination gives after it"
    )


# --------------------------------------------------------------------------------------------------- writing


@dataclass(frozen=True)
class Burn:
    """One impulsive manoeuvre: its moment, impulse (km/s in the message's frame) and a comment."""

    t: datetime
    dv_km_s: tuple[float, float, float]
    comment: str


@dataclass(frozen=True)
class Segment:
    """One OEM segment: an object's states at times ``t`` (GCRF; km, km/s as (3, N) rows ``r``, ``v``)."""

    object_name: str
    object_id: str
    comment: str
    t: Sequence[datetime]
    r: Any
    v: Any


def _serialise(message: Any, fmt: Format) -> str:
    from ccsds_ndm.mapping import NDMFileFormats
    from ccsds_ndm.ndm_io import NdmIo

    if fmt not in FORMATS:
        raise ValueError(f"format {fmt!r}: kvn or xml")
    text = NdmIo().to_string(message, NDMFileFormats.KVN if fmt == "kvn" else NDMFileFormats.XML)
    return text if text.endswith("\n") else text + "\n"


def _header(created: datetime, originator: str) -> Any:
    from ccsds_ndm.models.ndmxml4.ndmxml_4_0_0_common_4_0 import OdmHeader

    return OdmHeader(creation_date=ccsds_time_text(created), originator=originator)


def _km(x: float) -> Any:
    from ccsds_ndm.models.ndmxml4.ndmxml_4_0_0_common_4_0 import PositionTypeUo, PositionUnits

    return PositionTypeUo(value=round(float(x), 6), units=PositionUnits.KM)  # millimetres


def _km_s(x: float) -> Any:
    from ccsds_ndm.models.ndmxml4.ndmxml_4_0_0_common_4_0 import VelocityTypeUo, VelocityUnits

    return VelocityTypeUo(value=round(float(x), 9), units=VelocityUnits.KM_S)  # micrometres a second


def opm_message(
    *,
    created: datetime,
    originator: str,
    object_name: str,
    object_id: str,
    epoch: datetime,
    r_km: Sequence[float],
    v_km_s: Sequence[float],
    comment: str,
    burns: Sequence[Burn] = (),
    fmt: Format = "kvn",
) -> str:
    """A CCSDS OPM 3.0 (GCRF, UTC): a state at ``epoch`` and each burn as an impulsive manoeuvre (duration 0, no
    mass change: the observer's mass is not planned)."""
    from ccsds_ndm.models.ndmxml4 import ndmxml_4_0_0_common_4_0 as common
    from ccsds_ndm.models.ndmxml4 import ndmxml_4_0_0_opm_3_0 as opm
    from ccsds_ndm.models.ndmxml4.ndmxml_4_0_0_master_4_0 import Opm

    state = common.StateVectorType(
        comment=[comment],
        epoch=ccsds_time_text(epoch),
        x=_km(r_km[0]),
        y=_km(r_km[1]),
        z=_km(r_km[2]),
        x_dot=_km_s(v_km_s[0]),
        y_dot=_km_s(v_km_s[1]),
        z_dot=_km_s(v_km_s[2]),
    )
    manoeuvres = [
        opm.ManeuverParametersType(
            comment=[b.comment],
            man_epoch_ignition=ccsds_time_text(b.t),
            man_duration=common.DurationType(value=0.0, units=common.TimeUnits.S),
            man_delta_mass=common.DeltamassTypeZ(value=0.0, units=common.MassUnits.KG),
            man_ref_frame="GCRF",
            man_dv_1=_km_s(b.dv_km_s[0]),
            man_dv_2=_km_s(b.dv_km_s[1]),
            man_dv_3=_km_s(b.dv_km_s[2]),
        )
        for b in burns
    ]
    message = Opm(
        header=_header(created, originator),
        body=opm.OpmBody(
            segment=opm.OpmSegment(
                metadata=opm.OpmMetadata(
                    object_name=object_name,
                    object_id=object_id,
                    center_name="EARTH",
                    ref_frame="GCRF",
                    time_system="UTC",
                ),
                data=opm.OpmData(state_vector=state, maneuver_parameters=manoeuvres),
            )
        ),
    )  # its version attributes are fixed by the schema: CCSDS_OPM_VERS 3.0
    return _serialise(message, fmt)


def oem_message(*, created: datetime, originator: str, segments: Sequence[Segment], fmt: Format = "kvn") -> str:
    """A CCSDS OEM 3.0 (GCRF, UTC): each segment's states, to be interpolated by Lagrange's of degree 7."""
    from ccsds_ndm.models.ndmxml4 import ndmxml_4_0_0_common_4_0 as common
    from ccsds_ndm.models.ndmxml4 import ndmxml_4_0_0_oem_3_0 as oem
    from ccsds_ndm.models.ndmxml4.ndmxml_4_0_0_master_4_0 import Oem

    pieces = []
    for seg in segments:
        if len(seg.t) == 0:
            continue
        start, stop = ccsds_time_text(seg.t[0]), ccsds_time_text(seg.t[-1])
        pieces.append(
            oem.OemSegment(
                metadata=oem.OemMetadata(
                    object_name=seg.object_name,
                    object_id=seg.object_id,
                    center_name="EARTH",
                    ref_frame="GCRF",
                    time_system="UTC",
                    start_time=start,
                    useable_start_time=start,
                    useable_stop_time=stop,
                    stop_time=stop,
                    interpolation="LAGRANGE",
                    interpolation_degree=7,
                ),
                data=oem.OemData(
                    comment=[seg.comment],
                    state_vector=[
                        common.StateVectorAccType(
                            epoch=ccsds_time_text(t),
                            x=_km(seg.r[0][k]),
                            y=_km(seg.r[1][k]),
                            z=_km(seg.r[2][k]),
                            x_dot=_km_s(seg.v[0][k]),
                            y_dot=_km_s(seg.v[1][k]),
                            z_dot=_km_s(seg.v[2][k]),
                        )
                        for k, t in enumerate(seg.t)
                    ],
                ),
            )
        )
    message = Oem(header=_header(created, originator), body=oem.OemBody(segment=pieces))  # CCSDS_OEM_VERS 3.0
    return _serialise(message, fmt)


def convert(text: str, kind: Literal["OEM", "OPM"], fmt: Format) -> str:
    """A message this module wrote, in the other form (KVN to XML or back): read and written by ccsds-ndm."""
    from ccsds_ndm.ndm_io import NdmIo

    message = NdmIo().from_string(text)
    if type(message).__name__.upper() != kind:
        raise ValueError(f"this is a {type(message).__name__.upper()}, not an {kind}")
    return _serialise(message, fmt)


def _scalar_last(quaternion_wxyz: Sequence[float]) -> tuple[float, float, float, float]:
    """A quaternion given scalar first, as ADM writes it: unit, scalar last (Q1, Q2, Q3, QC), with QC >= 0."""
    w, x, y, z = (float(q) for q in quaternion_wxyz)
    norm = (w * w + x * x + y * y + z * z) ** 0.5
    sign = -1.0 if w < 0 else 1.0
    return sign * x / norm, sign * y / norm, sign * z / norm, sign * w / norm


def apm_message(
    *,
    created: datetime,
    originator: str,
    object_name: str,
    object_id: str,
    epoch: datetime,
    quaternion_wxyz: Sequence[float],
    comments: Sequence[str] = (),
    fmt: Format = "kvn",
) -> str:
    """A CCSDS APM 2.0 (ADM, 504.0-B-2; UTC): one attitude at ``epoch`` as a quaternion from GCRF to the body
    (REF_FRAME_A GCRF, REF_FRAME_B SC_BODY_1). ``quaternion_wxyz`` (scalar first) is the rotation that takes GCRF's
    axes onto the body's: the quaternion of the body-to-GCRF matrix, whose columns are the body axes in GCRF. It is
    written scalar last (Q1..Q3, QC) with QC >= 0.

    The XML is ccsds-ndm's. The KVN is written here: ADM 2.0 puts the quaternion between QUAT_START and QUAT_STOP,
    which ccsds-ndm's KVN writer leaves out (its XML and the standard's sample messages agree with this layout)."""
    from ccsds_ndm.models.ndmxml4 import ndmxml_4_0_0_apm_2_0 as apm
    from ccsds_ndm.models.ndmxml4 import ndmxml_4_0_0_common_4_0 as common
    from ccsds_ndm.models.ndmxml4.ndmxml_4_0_0_master_4_0 import Apm

    if fmt not in FORMATS:
        raise ValueError(f"format {fmt!r}: kvn or xml")
    q1, q2, q3, qc = _scalar_last(quaternion_wxyz)
    if fmt == "kvn":
        lines = [
            "CCSDS_APM_VERS = 2.0",
            f"CREATION_DATE  = {ccsds_time_text(created)}",
            f"ORIGINATOR     = {originator}",
            "",
            *(f"COMMENT {c}" for c in comments),
            f"OBJECT_NAME    = {object_name}",
            f"OBJECT_ID      = {object_id}",
            "CENTER_NAME    = EARTH",
            "TIME_SYSTEM    = UTC",
            "",
            f"EPOCH          = {ccsds_time_text(epoch)}",
            "",
            "QUAT_START",
            "REF_FRAME_A    = GCRF",
            "REF_FRAME_B    = SC_BODY_1",
            f"Q1             = {q1:.12f}",
            f"Q2             = {q2:.12f}",
            f"Q3             = {q3:.12f}",
            f"QC             = {qc:.12f}",
            "QUAT_STOP",
        ]
        return "\n".join(lines) + "\n"
    state = common.QuaternionStateType(
        ref_frame_a="GCRF",
        ref_frame_b="SC_BODY_1",
        quaternion=common.QuaternionType(q1=q1, q2=q2, q3=q3, qc=qc),
    )
    message = Apm(
        header=common.AdmHeader(creation_date=ccsds_time_text(created), originator=originator),
        body=apm.ApmBody(
            segment=apm.ApmSegment(
                metadata=apm.ApmMetadata(
                    comment=list(comments),
                    object_name=object_name,
                    object_id=object_id,
                    center_name="EARTH",
                    time_system="UTC",
                ),
                data=apm.ApmData(epoch=ccsds_time_text(epoch), quaternion_state=[state]),
            )
        ),
    )
    return _serialise(message, fmt)


def aem_message(
    *,
    created: datetime,
    originator: str,
    object_name: str,
    object_id: str,
    times: Sequence[datetime],
    quaternions_wxyz: Sequence[Sequence[float]],
    comments: Sequence[str] = (),
    fmt: Format = "kvn",
) -> str:
    """A CCSDS AEM 2.0 (ADM, 504.0-B-2; UTC): one segment of quaternions from GCRF to the body (REF_FRAME_A GCRF,
    REF_FRAME_B SC_BODY_1; each as ``apm_message`` states it, scalar last with QC >= 0), at ``times``.

    The XML is ccsds-ndm's. The KVN is written here: its data lines are ``EPOCH Q1 Q2 Q3 QC``, where ccsds-ndm's KVN
    writer puts QC first."""
    from ccsds_ndm.models.ndmxml4 import ndmxml_4_0_0_aem_2_0 as aem
    from ccsds_ndm.models.ndmxml4 import ndmxml_4_0_0_common_4_0 as common
    from ccsds_ndm.models.ndmxml4.ndmxml_4_0_0_master_4_0 import Aem

    if len(times) != len(quaternions_wxyz) or len(times) < 2:
        raise ValueError("an AEM needs two or more times, each with its quaternion")
    states = []
    for t, q_wxyz in zip(times, quaternions_wxyz, strict=True):
        q1, q2, q3, qc = _scalar_last(q_wxyz)
        states.append(
            common.AttitudeStateType(
                quaternion_ephemeris=common.QuaternionEphemerisType(
                    epoch=ccsds_time_text(t), quaternion=common.QuaternionType(q1=q1, q2=q2, q3=q3, qc=qc)
                )
            )
        )
    if fmt == "kvn":
        rows = []
        for st in states:
            q = st.quaternion_ephemeris.quaternion
            rows.append(f"{st.quaternion_ephemeris.epoch}  {q.q1:.12f}  {q.q2:.12f}  {q.q3:.12f}  {q.qc:.12f}")
        lines = [
            "CCSDS_AEM_VERS = 2.0",
            f"CREATION_DATE  = {ccsds_time_text(created)}",
            f"ORIGINATOR     = {originator}",
            "",
            "META_START",
            *(f"COMMENT {c}" for c in comments),
            f"OBJECT_NAME    = {object_name}",
            f"OBJECT_ID      = {object_id}",
            "CENTER_NAME    = EARTH",
            "REF_FRAME_A    = GCRF",
            "REF_FRAME_B    = SC_BODY_1",
            "TIME_SYSTEM    = UTC",
            f"START_TIME     = {ccsds_time_text(times[0])}",
            f"STOP_TIME      = {ccsds_time_text(times[-1])}",
            "ATTITUDE_TYPE  = QUATERNION",
            "META_STOP",
            "",
            "DATA_START",
            *rows,
            "DATA_STOP",
        ]
        return "\n".join(lines) + "\n"
    message = Aem(
        header=common.AdmHeader(creation_date=ccsds_time_text(created), originator=originator),
        body=aem.AemBody(
            segment=[
                aem.AemSegment(
                    metadata=aem.AemMetadata(
                        comment=list(comments),
                        object_name=object_name,
                        object_id=object_id,
                        center_name="EARTH",
                        ref_frame_a="GCRF",
                        ref_frame_b="SC_BODY_1",
                        time_system="UTC",
                        start_time=ccsds_time_text(times[0]),
                        stop_time=ccsds_time_text(times[-1]),
                        attitude_type="QUATERNION",
                    ),
                    data=aem.AemData(attitude_state=states),
                )
            ]
        ),
    )
    return _serialise(message, fmt)
