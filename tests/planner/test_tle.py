import pytest

from planner.errors import TLEError
from planner.tle import parse_tle
from tests.utils.orbits import ISS_L1, ISS_L2


def test_valid_tle_epoch():
    tle = parse_tle(ISS_L1, ISS_L2)
    assert tle.catalog_number == "25544"
    assert tle.epoch.isoformat().startswith("2008-09-20T12:25:40")


@pytest.mark.parametrize(
    ("l1", "l2", "message"),
    [
        (ISS_L1[:-1], ISS_L2, "68 characters"),
        (ISS_L1[:-1] + "8", ISS_L2, "checksum"),
        (ISS_L1, ISS_L2[:-1] + "0", "line 2 checksum"),
        (ISS_L2, ISS_L1, "must start with '1 '"),
        (ISS_L1.replace("U", "\u00dc"), ISS_L2, "non-ASCII"),
        (ISS_L1, ISS_L2.replace("25544", "25545"), "checksum"),
    ],
)
def test_malformed_tles_say_what_is_wrong(l1, l2, message):
    with pytest.raises(TLEError, match=message):
        parse_tle(l1, l2)
