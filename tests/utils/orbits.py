"""Factories for the paper's Table 1 orbits and a reference TLE."""

from datetime import UTC, datetime

from planner.examples import PAPER_EPOCH, PAPER_OBSERVER, PAPER_STATION, PAPER_TARGET  # noqa: F401

# ISS, the TLE of the sgp4 and skyfield documentation.
ISS_L1 = "1 25544U 98067A   08264.51782528 -.00002182  00000-0 -11606-4 0  2927"
ISS_L2 = "2 25544  51.6416 247.4627 0006703 130.5360 325.0288 15.72125391563537"
ISS_EPOCH = datetime(2008, 9, 20, 12, 0, tzinfo=UTC)

# Made with sgp4's own sgp4init + export_tle (valid checksums), epoch 2024-03-01 06:00 UTC:
# a sun-synchronous LEO at 97.8 deg and a Molniya orbit (e 0.72, i 63.4, 12-h period, SDP4).
SSO_L1 = "1 43001U          24061.25000000  .00000000  00000-0  20000-4 0    07"
SSO_L2 = "2 43001  97.8000 120.0000 0012000  90.0000 270.0000 14.80000000    01"
MOLNIYA_L1 = "1 43002U          24061.25000000  .00000000  00000-0  20000-4 0    08"
MOLNIYA_L2 = "2 43002  63.4000  40.0000 7200000 270.0000  10.0000  2.00570000    01"
TLE_2024_EPOCH = datetime(2024, 3, 1, 6, 0, tzinfo=UTC)


def opm_kvn(r_km, v_km_s, epoch="2008-09-20T12:25:40.104192", frame="GCRF", version="3.0"):
    """An OPM in KVN as 502.0-B-3 lays it out, written here by hand (the reader is what is tested)."""
    state = "".join(
        f"{k} = {x:.9f} [{'km' if n < 3 else 'km/s'}]\n"
        for n, (k, x) in enumerate(zip(("X", "Y", "Z", "X_DOT", "Y_DOT", "Z_DOT"), [*r_km, *v_km_s], strict=True))
    )
    return (
        f"CCSDS_OPM_VERS = {version}\nCREATION_DATE = 2026-12-01T00:00:00\nORIGINATOR = TEST\n"
        f"OBJECT_NAME = ISS (ZARYA)\nOBJECT_ID = 1998-067A\nCENTER_NAME = EARTH\nREF_FRAME = {frame}\n"
        f"TIME_SYSTEM = UTC\nCOMMENT the state\nEPOCH = {epoch}\n" + state
    )


def oem_kvn(epochs, r_km, v_km_s, frame="GCRF", version="3.0", segments=1):
    """An OEM in KVN as 502.0-B-3 lays it out (META_START..META_STOP, then a data line a state), written here by hand
    (the reader is what is tested); ``segments`` repeats the one segment after a COMMENT (a manoeuvre's)."""
    head = f"CCSDS_OEM_VERS = {version}\nCREATION_DATE = 2026-12-01T00:00:00\nORIGINATOR = TEST\n"
    lines = [
        f"{t:%Y-%m-%dT%H:%M:%S.%f} " + " ".join(f"{x:.9f}" for x in (*r, *v))
        for t, r, v in zip(epochs, r_km, v_km_s, strict=True)
    ]
    meta = (
        f"META_START\nOBJECT_NAME = ISS (ZARYA)\nOBJECT_ID = 1998-067A\nCENTER_NAME = EARTH\nREF_FRAME = {frame}\n"
        f"TIME_SYSTEM = UTC\nSTART_TIME = {epochs[0]:%Y-%m-%dT%H:%M:%S.%f}\nSTOP_TIME = {epochs[-1]:%Y-%m-%dT%H:%M:%S.%f}\n"
        "META_STOP\n"
    )
    return head + "".join(meta + "\n".join(lines) + "\n" for _ in range(segments))
