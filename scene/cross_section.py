"""The target's mean radar cross section by aspect: what the planner's radar equation needs of the target model.

A table over the sphere of lines of sight (target to radar) in the target's LVLH frame, for a target
flown at its nominal attitude (body axes along LVLH: radial, along-track, orbit normal). Each entry is
the physical-optics echo of the target's mesh (``inference.simulation.po``, single bounce, smooth facets)
averaged over the band and the aperture of the paper's Table 3 radar (15 GHz, 1.6 GHz, 5.1 deg), i.e. the
mean of |s(K)|^2 over the frame's k-patch, which is the cross section the image's energy carries
(Parseval). The table is made once per built-in target and shipped (``scene/data/<target>-rcs.npz``,
``python -m scene.cross_section build``: about a minute a target); a lookup interpolates log sigma
bilinearly in azimuth and elevation.
"""

from __future__ import annotations

import argparse
import hashlib
import math
import sys
import time
from functools import lru_cache
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from inference.simulation.mesh import Mesh
from inference.simulation.po import POOptions, po_echo, prepared
from inference.simulation.radar import Imager, Radar
from inference.simulation.targets import BUILTIN_TARGETS, builtin_target
from planner.radar import CrossSection
from scene.errors import SceneError

Vec = NDArray[np.float64]

DATA = Path(__file__).parent / "data"
STEP_DEG = 10.0  # the table's grid in azimuth and elevation (the aperture averages over 5.1 deg)
GRID_SAMPLES = 64  # k-samples a side of the patch averaged (5.1 / 64 = 0.08 deg: a 5.5 m plate's lobe is 0.2 deg)
FACET_M = 0.2


def grid() -> tuple[Vec, Vec]:
    """The table's azimuths (deg, [0, 360) from radial toward along-track) and elevations (deg, -90..90 toward
    the orbit normal)."""
    return np.arange(0.0, 360.0, STEP_DEG), np.arange(-90.0, 90.0 + 0.5 * STEP_DEG, STEP_DEG)


def direction(azimuth_deg: float, elevation_deg: float) -> Vec:
    """The unit line of sight (LVLH) at an azimuth and elevation of the table."""
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    return np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])


def observation_rotation(los: Vec) -> Vec:
    """Body (= LVLH) to an observation frame with X along ``los``; the aperture sweeps toward Y, taken across the
    orbit normal (a pass's line of sight mostly turns in the orbit plane), or along-track where ``los`` is the
    normal."""
    x = np.asarray(los, float) / np.linalg.norm(los)
    y = np.cross([0.0, 0.0, 1.0], x)
    if np.linalg.norm(y) < 1e-6:
        y = np.array([0.0, 1.0, 0.0])
    y /= np.linalg.norm(y)
    return np.stack([x, y, np.cross(x, y)])


def mean_rcs_m2(mesh: Mesh, los: Vec, samples: int = GRID_SAMPLES) -> float:
    """A mesh's PO cross section along ``los`` (LVLH = body), averaged over the Table 3 band and aperture, m^2."""
    pm = prepared(mesh, FACET_M)
    imager = Imager(Radar(n_range=samples, n_azimuth=samples))
    echo = po_echo(pm, observation_rotation(los), imager, POOptions(facet_m=FACET_M), np.random.default_rng(0))
    return float(np.mean(np.abs(echo) ** 2))


def build(target_name: str, out: Path | None = None, progress: bool = True) -> Path:
    """Compute and write the table of ``target_name``; returns its path."""
    az, el = grid()
    mesh = target_mesh(target_name)
    table = np.zeros((el.size, az.size))
    clock = time.perf_counter()
    for i, e in enumerate(el):
        for j, a in enumerate(az):
            if abs(e) == 90.0 and j > 0:  # the poles: one direction
                table[i, j] = table[i, 0]
                continue
            table[i, j] = mean_rcs_m2(mesh, direction(a, e))
        if progress:
            print(f"{target_name}: elevation {e:+.0f} deg done, {time.perf_counter() - clock:.0f} s", file=sys.stderr)
    path = out or DATA / f"{target_name}-rcs.npz"
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(
        path,
        rcs_m2=table,
        azimuth_deg=az,
        elevation_deg=el,
        mesh_sha256=np.array(mesh_fingerprint(mesh)),
    )
    return path


def target_mesh(target_name: str) -> Mesh:
    """A built-in target's mesh (every built-in target has one)."""
    mesh = builtin_target(target_name).mesh
    if mesh is None:
        raise SceneError(["target"], f"target {target_name!r} has no mesh: no cross section can be computed")
    return mesh


def mesh_fingerprint(mesh: Mesh) -> str:
    """The sha256 of a mesh (vertices and faces): a table made from another mesh is refused."""
    h = hashlib.sha256(np.ascontiguousarray(mesh.vertices, np.float64).tobytes())
    h.update(np.ascontiguousarray(mesh.faces, np.int64).tobytes())
    return h.hexdigest()


class CrossSectionTable:
    """A shipped table as the planner's ``CrossSection``: unit lines of sight (3, N) in LVLH to m^2 (N,)."""

    def __init__(self, rcs_m2: Vec, azimuth_deg: Vec, elevation_deg: Vec) -> None:
        self.log_rcs = np.log10(np.maximum(rcs_m2, 1e-12))
        self.azimuth_deg = azimuth_deg
        self.elevation_deg = elevation_deg

    def __call__(self, los_lvlh: Vec) -> Vec:
        u = np.asarray(los_lvlh, float).reshape(3, -1)
        u = u / np.linalg.norm(u, axis=0)
        el = np.degrees(np.arcsin(np.clip(u[2], -1.0, 1.0)))
        az = np.mod(np.degrees(np.arctan2(u[1], u[0])), 360.0)
        step_a = self.azimuth_deg[1] - self.azimuth_deg[0]
        step_e = self.elevation_deg[1] - self.elevation_deg[0]
        fa = (az - self.azimuth_deg[0]) / step_a
        fe = np.clip((el - self.elevation_deg[0]) / step_e, 0.0, self.elevation_deg.size - 1.000001)
        ja, ie = np.floor(fa).astype(int), np.floor(fe).astype(int)
        wa, we = fa - ja, fe - ie
        n = self.azimuth_deg.size
        ja0, ja1 = ja % n, (ja + 1) % n
        t = self.log_rcs
        value = (1 - we) * ((1 - wa) * t[ie, ja0] + wa * t[ie, ja1]) + we * (
            (1 - wa) * t[ie + 1, ja0] + wa * t[ie + 1, ja1]
        )
        return np.asarray(10.0**value)


@lru_cache(maxsize=4)
def for_target(target_name: str) -> CrossSection:
    """The shipped table of a built-in target as a ``CrossSection``; SceneError where there is none or it was made
    from another mesh."""
    path = DATA / f"{target_name}-rcs.npz"
    if not path.is_file():
        raise SceneError(
            ["target"], f"no cross-section table for target {target_name!r}: python -m scene.cross_section build"
        )
    with np.load(path, allow_pickle=False) as f:
        if str(f["mesh_sha256"]) != mesh_fingerprint(target_mesh(target_name)):
            raise SceneError(
                ["target"],
                f"{path.name} was made from another mesh of {target_name!r}: python -m scene.cross_section build",
            )
        return CrossSectionTable(f["rcs_m2"], f["azimuth_deg"], f["elevation_deg"])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m scene.cross_section", description=__doc__.splitlines()[0])
    parser.add_argument("command", choices=["build"])
    parser.add_argument("--target", action="append", choices=sorted(BUILTIN_TARGETS))
    args = parser.parse_args(argv)
    for name in args.target or sorted(BUILTIN_TARGETS):
        print(build(name))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
