"""Making the shipped cross-section tables (``scene.cross_section``): the target's PO echo averaged over the band
and aperture, on a 10-deg grid of lines of sight. ``python -m scene.cross_section_build [--target NAME]``.
"""

from __future__ import annotations

import argparse
import hashlib
import sys
import time
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from inference.simulation.mesh import Mesh
from inference.simulation.po import POOptions, po_echo, prepared
from inference.simulation.radar import Imager, Radar
from inference.simulation.targets import BUILTIN_TARGETS, builtin_target
from scene.cross_section import DATA, direction, grid
from scene.errors import SceneError

Vec = NDArray[np.float64]

GRID_SAMPLES = 64  # k-samples a side of the patch averaged (5.1 / 64 = 0.08 deg: a 5.5 m plate's lobe is 0.2 deg)
FACET_M = 0.2


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
    """The sha256 of a mesh (vertices to the micrometre, and faces): a table made from another mesh is refused.

    The built-in meshes are built with trigonometry whose last bits differ between CPUs (AVX2 against AVX-512):
    their vertices are hashed as whole micrometres, the same on every machine."""
    microns = np.rint(np.asarray(mesh.vertices, np.float64) * 1e6).astype(np.int64)
    h = hashlib.sha256(np.ascontiguousarray(microns).tobytes())
    h.update(np.ascontiguousarray(mesh.faces, np.int64).tobytes())
    return h.hexdigest()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m scene.cross_section_build", description=(__doc__ or "").splitlines()[0]
    )
    parser.add_argument("--target", action="append", choices=sorted(BUILTIN_TARGETS))
    args = parser.parse_args(argv)
    for name in args.target or sorted(BUILTIN_TARGETS):
        print(build(name))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
