"""Two-line element sets: validation of the line format and checksums."""

from __future__ import annotations

from dataclasses import dataclass
from datetime import UTC, datetime, timedelta

from planner.errors import TLEError


@dataclass(frozen=True, slots=True)
class TLE:
    """A validated two-line element set."""

    line1: str
    line2: str

    @property
    def catalog_number(self) -> str:
        return self.line1[2:7].strip()

    @property
    def epoch(self) -> datetime:
        """Return the TLE epoch as a UTC datetime."""
        yy = int(self.line1[18:20])
        year = 2000 + yy if yy < 57 else 1900 + yy
        day = float(self.line1[20:32])
        return datetime(year, 1, 1, tzinfo=UTC) + timedelta(days=day - 1.0)


def tle_checksum(line: str) -> int:
    """Return the modulo-10 checksum of the first 68 characters (digits count, '-' counts 1).

    >>> tle_checksum("1 25544U 98067A   08264.51782528 -.00002182  00000-0 -11606-4 0  2927")
    7
    """
    total = 0
    for ch in line[:68]:
        if ch.isdigit():
            total += int(ch)
        elif ch == "-":
            total += 1
    return total % 10


def parse_tle(line1: str, line2: str, field: str = "tle") -> TLE:
    """Validate two TLE lines and return them as a TLE.

    Raises TLEError, naming which line is wrong and how, for: non-ASCII text, lines
    that are not 69 characters, wrong line numbers, mismatched catalogue numbers,
    bad checksums and fields that are not numbers.
    """
    lines = []
    for number, raw in ((1, line1), (2, line2)):
        if not isinstance(raw, str):
            raise TLEError(f"line {number} must be a string", field=field)
        line = raw.rstrip("\r\n ")
        if not line.isascii():
            raise TLEError(f"line {number} contains non-ASCII characters", field=field)
        if len(line) != 69:
            raise TLEError(f"line {number} has {len(line)} characters; a TLE line has 69", field=field)
        if line[0] != str(number) or line[1] != " ":
            raise TLEError(f"line {number} must start with '{number} '", field=field)
        if not line[68].isdigit():
            raise TLEError(f"line {number} must end with a checksum digit", field=field)
        expected = tle_checksum(line)
        if int(line[68]) != expected:
            raise TLEError(f"line {number} checksum is {line[68]} but its characters sum to {expected}", field=field)
        lines.append(line)
    l1, l2 = lines
    if l1[2:7] != l2[2:7]:
        raise TLEError(f"catalogue numbers differ between lines: {l1[2:7]!r} and {l2[2:7]!r}", field=field)
    numeric = {
        "epoch": l1[18:32],
        "inclination": l2[8:16],
        "RAAN": l2[17:25],
        "eccentricity": "0." + l2[26:33],
        "argument of perigee": l2[34:42],
        "mean anomaly": l2[43:51],
        "mean motion": l2[52:63],
    }
    for name, text in numeric.items():
        try:
            float(text)
        except ValueError:
            raise TLEError(f"{name} field {text.strip()!r} is not a number", field=field) from None
    if not 0.0 <= float(l2[8:16]) <= 180.0:
        raise TLEError(f"inclination {l2[8:16].strip()} deg is outside [0, 180]", field=field)
    if float(l2[52:63]) <= 0.0:
        raise TLEError("mean motion must be positive", field=field)
    tle = TLE(l1, l2)
    from sgp4.api import Satrec

    sat = Satrec.twoline2rv(l1, l2)
    if sat.error:
        raise TLEError(f"SGP4 rejects this TLE (error {sat.error})", field=field)
    return tle


def tle_lines(text_or_lines: str | list[str], field: str = "tle") -> tuple[str, str, str | None]:
    """Return the two element lines and the name (or None) of a TLE given as 2 lines, 3 lines (3LE), or a text block.

    A 3LE's first line is the satellite's name, with or without CelesTrak's leading ``0 ``.

    >>> tle_lines(["0 ISS (ZARYA)", "1 a", "2 b"])
    ('1 a', '2 b', 'ISS (ZARYA)')
    """
    lines = text_or_lines.splitlines() if isinstance(text_or_lines, str) else list(text_or_lines)
    lines = [ln.rstrip("\r\n ") for ln in lines if ln.strip()]
    if len(lines) == 2:
        return lines[0], lines[1], None
    if len(lines) == 3:
        name = lines[0][2:] if lines[0].startswith("0 ") else lines[0]
        return lines[1], lines[2], name.strip()
    raise TLEError(f"a TLE is 2 lines, or 3 with a name line first; this one has {len(lines)}", field=field)


def split_tles(text_or_lines: str | list[str], field: str = "tle") -> list[tuple[str, str, str | None]]:
    """Every element set of a TLE text (CelesTrak's 2LE or 3LE files): ``(line1, line2, name or None)`` each.

    >>> [s[2] for s in split_tles(["0 A", "1 x", "2 y", "B", "1 z", "2 w"])]
    ['A', 'B']
    """
    lines = text_or_lines.splitlines() if isinstance(text_or_lines, str) else list(text_or_lines)
    lines = [ln.rstrip("\r\n ") for ln in lines if ln.strip()]
    sets: list[tuple[str, str, str | None]] = []
    k = 0
    while k < len(lines):
        one, two = (lines[k + j] if k + j < len(lines) else "" for j in (1, 2))
        if lines[k].startswith("1 ") and one.startswith("2 "):
            sets.append((lines[k], one, None))
            k += 2
        elif not lines[k].startswith(("1 ", "2 ")) and one.startswith("1 ") and two.startswith("2 "):
            name = lines[k][2:] if lines[k].startswith("0 ") else lines[k]
            sets.append((one, two, name.strip()))
            k += 3
        else:
            raise TLEError(
                f"line {k + 1} ({lines[k][:24]!r}) is neither a name line nor the first line of an element set "
                "(sets are an optional name line, a line starting '1 ', a line starting '2 ')",
                field=field,
            )
    if not sets:
        raise TLEError("no element set (a line starting '1 ' followed by one starting '2 ') in the text", field=field)
    return sets


OMM_DEFAULTS = {
    "CLASSIFICATION_TYPE": "U",
    "OBJECT_ID": "",
    "EPHEMERIS_TYPE": 0,
    "ELEMENT_SET_NO": 999,
    "REV_AT_EPOCH": 0,
    "BSTAR": 0.0,
    "MEAN_MOTION_DOT": 0.0,
    "MEAN_MOTION_DDOT": 0.0,
    "NORAD_CAT_ID": 0,
}
OMM_REQUIRED = (
    "EPOCH",
    "MEAN_MOTION",
    "ECCENTRICITY",
    "INCLINATION",
    "RA_OF_ASC_NODE",
    "ARG_OF_PERICENTER",
    "MEAN_ANOMALY",
)


def tle_from_omm(fields: dict[str, object], field: str = "omm") -> TLE:
    """Return the TLE of a CCSDS OMM's mean elements (SGP4 / TLE theory), as CelesTrak serves them.

    sgp4's own OMM reader fills the satellite record; its TLE exporter writes the lines, so an
    OMM propagates exactly as the TLE it came from. Raises TLEError naming the field.
    """
    from sgp4 import exporter, omm
    from sgp4.api import Satrec

    missing = [k for k in OMM_REQUIRED if k not in fields]
    if missing:
        raise TLEError(
            f"the OMM has no {missing[0]}: an OMM for SGP4 gives {', '.join(OMM_REQUIRED)}", field=missing[0]
        )
    values = {**OMM_DEFAULTS, **fields}
    theory = str(fields.get("MEAN_ELEMENT_THEORY", "SGP4")).upper()
    if theory not in ("SGP4", "SGP4-XP", "SDP4"):
        raise TLEError(
            f"MEAN_ELEMENT_THEORY {theory!r}: only SGP4 mean elements can be used", field="MEAN_ELEMENT_THEORY"
        )
    from planner.ccsds import ccsds_time

    try:  # sgp4's reader takes calendar time only: a day-of-year epoch (CCSDS's other form) is written as one
        epoch = ccsds_time(str(values["EPOCH"]))
    except ValueError:
        raise TLEError(
            f"EPOCH {values['EPOCH']!r} is not a CCSDS time (YYYY-MM-DDThh:mm:ss or YYYY-DDDThh:mm:ss, UTC)",
            field="EPOCH",
        ) from None
    values["EPOCH"] = epoch.strftime("%Y-%m-%dT%H:%M:%S.%f")
    for key in OMM_REQUIRED[1:] + ("BSTAR", "MEAN_MOTION_DOT", "MEAN_MOTION_DDOT"):
        try:
            number = float(values[key])  # type: ignore[arg-type]
        except (TypeError, ValueError):
            raise TLEError(f"{key} {values[key]!r} is not a number", field=key) from None
        if number != number or number in (float("inf"), float("-inf")):
            raise TLEError(f"{key} must be finite", field=key)
    checks = (
        ("MEAN_MOTION", 0.05 < float(values["MEAN_MOTION"]) < 20.0, "revolutions a day, over 0.05 and under 20"),  # type: ignore[arg-type]
        ("ECCENTRICITY", 0.0 <= float(values["ECCENTRICITY"]) < 1.0, "in [0, 1)"),  # type: ignore[arg-type]
        ("INCLINATION", 0.0 <= float(values["INCLINATION"]) <= 180.0, "degrees in [0, 180]"),  # type: ignore[arg-type]
    )
    for key, ok, what in checks:
        if not ok:
            raise TLEError(f"{key} {values[key]} must be {what}", field=key)
    try:
        satnum = int(values["NORAD_CAT_ID"])  # type: ignore[call-overload]
    except (TypeError, ValueError):
        raise TLEError(f"NORAD_CAT_ID {values['NORAD_CAT_ID']!r} is not a whole number", field="NORAD_CAT_ID") from None
    if not 0 <= satnum <= 339_999:
        raise TLEError(f"NORAD_CAT_ID {satnum} does not fit a TLE (0 to 339999)", field="NORAD_CAT_ID")
    sat = Satrec()
    try:
        omm.initialize(sat, {k: str(v) for k, v in values.items()})
    except ValueError as exc:
        raise TLEError(f"the OMM cannot be read: {exc}", field="EPOCH" if "time data" in str(exc) else field) from None
    if sat.error:
        raise TLEError(f"SGP4 refuses these elements (error {sat.error})", field=field)
    line1, line2 = exporter.export_tle(sat)
    return parse_tle(line1, line2, field=field)


def omm_fields_from_text(text: str, kind: str) -> dict[str, object]:
    """Return the one OMM in CelesTrak's XML (``kind`` "xml") or CSV ("csv") text, as a field dict."""
    import io

    from sgp4 import omm

    try:
        records = list(omm.parse_xml(io.StringIO(text)) if kind == "xml" else omm.parse_csv(io.StringIO(text)))
    except Exception as exc:  # the readers raise whatever their parsers do  # noqa: BLE001
        raise TLEError(f"not a readable OMM {kind.upper()}: {str(exc)[:200]}", field=f"omm_{kind}") from None
    if len(records) != 1:
        raise TLEError(f"the OMM {kind.upper()} holds {len(records)} element sets; send one", field=f"omm_{kind}")
    version = records[0].get("CCSDS_OMM_VERS")
    if kind == "xml":
        import xml.etree.ElementTree as ET

        root = ET.fromstring(text)
        node = root if root.tag == "omm" else root.find(".//omm")
        version = None if node is None else node.get("version")
    if version not in (None, "", "2.0", "3.0"):
        raise TLEError(f"CCSDS_OMM_VERS {version!r}: this reads OMM 2.0 and 3.0", field="CCSDS_OMM_VERS")
    return dict(records[0])
