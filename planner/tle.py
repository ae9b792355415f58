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
