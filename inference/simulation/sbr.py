"""Shooting and bouncing rays (Ling, Chou & Lee 1989, IEEE Trans. AP-37:194): the second and third bounce of
physical optics (``POOptions.bounces``), as point sources the echo adds to the single-bounce facets.

Each lit facet launches ray tubes along the specular direction of the incident wave. A tube that hits the mesh
is reflected there (PEC: the field's sign flips at each reflection) and followed again. After every bounce
past the first, a tube radiates back to the radar from its last hit, by aperture integration over its
cross-section (a square of the tube's area): sin(k s u / 2) / (k s u / 2) in each of the two directions across
it, u the radar's direction's component across the exit direction. It radiates only where the exit point
sees the radar (a ray cast from it), so tubes that leave into the inside of a cavity are silent.

Tubes are sized to the wavelength, not to the mesh: a facet whose centre or corner rays hit anything is split
into tubes of at most ``tube_m`` (the default, 2.5 wavelengths at the paper's 2 cm, converges the dihedral's
main lobe and first sidelobes; tests/inference/simulation/test_po.py), while facets whose rays all leave
launch one tube each and cost one ray.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from inference.simulation.mesh import RayEngine, bisect

Vec = NDArray[np.float64]


def _basis(d: Vec) -> tuple[Vec, Vec]:
    """Two unit vectors across each direction in ``d`` (N, 3)."""
    helper = np.where(np.abs(d[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    a1 = np.cross(d, helper)
    a1 /= np.linalg.norm(a1, axis=1, keepdims=True)
    return a1, np.cross(d, a1)


def tube_pattern(k: float, side: Vec, d: Vec, los: Vec) -> Vec:
    """The far-field pattern toward ``los`` of square apertures of ``side`` radiating along ``d`` (N, 3), peak 1.

    sin(k s u / 2) / (k s u / 2) for each of the two directions across the aperture (np.sinc's pi taken out),
    times the obliquity (1 + cos) / 2 of aperture integration.
    """
    a1, a2 = _basis(d)
    s1, s2 = a1 @ los, a2 @ los
    half = k * side / (2.0 * np.pi)
    return np.asarray(np.sinc(half * s1) * np.sinc(half * s2) * np.clip((d @ los + 1.0) / 2.0, 0.0, 1.0))


def launch_tubes(
    engine: RayEngine, rot: Vec, tri_obs: Vec, nrm_obs: Vec, los: Vec, tube_m: float
) -> tuple[Vec, Vec, Vec]:
    """The tubes the lit facets launch: their start points, normals (toward the radar) and cross-sections (obs frame).

    A facet whose centroid or inset corner rays hit the mesh is split into tubes of at most ``tube_m``; the
    others launch one tube each (it leaves the target, so its size does not matter).
    """
    d = -los + 2.0 * (nrm_obs @ los)[:, None] * nrm_obs
    cen = tri_obs.mean(axis=1)
    probes = np.concatenate([cen[:, None], 0.8 * tri_obs + 0.2 * cen[:, None]], axis=1)  # (F, 4, 3)
    lift = 1e-4 * nrm_obs[:, None, :]
    dirs = np.repeat(d[:, None, :], 4, axis=1)
    hits = engine.first_hit(((probes + lift).reshape(-1, 3)) @ rot, np.ascontiguousarray(dirs.reshape(-1, 3) @ rot))
    busy = (hits.reshape(-1, 4) >= 0).any(axis=1)
    pieces, parent = bisect(tri_obs[busy], tube_m)
    tubes = np.concatenate([tri_obs[~busy], pieces])
    owner = np.concatenate([np.flatnonzero(~busy), np.flatnonzero(busy)[parent]])
    start = tubes.mean(axis=1)
    areas = 0.5 * np.linalg.norm(np.cross(tubes[:, 1] - tubes[:, 0], tubes[:, 2] - tubes[:, 0]), axis=1)
    nrm = nrm_obs[owner]
    return start, nrm, areas * np.abs(nrm @ los)


def bounce_sources(
    engine: RayEngine,
    rot: Vec,
    normals_body: Vec,
    two_sided: NDArray[np.bool_],
    start: Vec,
    nrm: Vec,
    tube: Vec,
    los: Vec,
    lam: float,
    bounces: int,
) -> tuple[Vec, NDArray[np.complex128]]:
    """Follow the tubes (obs frame ``start``, ``nrm``, cross-sections ``tube``) and return their echoes as point sources.

    Each echo's point lies at the range of its two-way path and at the cross-range of its last two hits'
    midpoint; its phase is the path's, so its amplitude is real: sign x sqrt(4 pi) / lambda x tube x pattern.
    """
    k = 2.0 * math.pi / lam
    d = -los + 2.0 * (nrm @ los)[:, None] * nrm  # reflected direction (incidence along -los)
    path = -(start @ los)  # path from the reference plane through the origin to the first hit
    here = start
    sign = 1.0
    pts_out, amp_out = [np.zeros((0, 3))], [np.zeros(0, np.complex128)]
    normals_obs = normals_body @ rot.T
    los_body = np.ascontiguousarray(np.broadcast_to(los @ rot, (1, 3)))
    for _ in range(bounces - 1):
        hit, where_body = engine.first_hit_location((here + 1e-4 * d) @ rot, np.ascontiguousarray(d @ rot))
        ok = hit >= 0
        if not ok.any():
            break
        hit, where, d, path, tube, prev = hit[ok], where_body[ok] @ rot.T, d[ok], path[ok], tube[ok], here[ok]
        path = path + np.linalg.norm(where - prev, axis=1)
        n = normals_obs[hit]
        n = n * np.where((n * d).sum(1) > 0, -1.0, 1.0)[:, None]  # the side the ray arrives on
        closed_back = ~two_sided[hit] & ((normals_obs[hit] * d).sum(1) > 0)
        d = d - 2.0 * (d * n).sum(1)[:, None] * n
        sign = -sign
        out = ~closed_back & (d @ los > 0)
        # the exit must see the radar: a ray from the hit toward it, lifted off the surface on the arrival side
        probe = np.flatnonzero(out)
        if len(probe):
            origin = (where[probe] + 1e-4 * n[probe] + 1e-5 * los) @ rot
            blocked = engine.first_hit(origin, np.repeat(los_body, len(probe), axis=0)) >= 0
            out[probe[blocked]] = False
        pattern = tube_pattern(k, np.sqrt(tube), d, los)
        total = path - where @ los  # the two-way path, from the reference plane through the origin and back
        mid = 0.5 * (prev + where)
        p_eq = mid + (-total / 2.0 - mid @ los)[:, None] * los
        amp = sign * math.sqrt(4.0 * math.pi) / lam * tube * pattern + 0j
        pts_out.append(p_eq[out])
        amp_out.append(amp[out])
        keep = ~closed_back
        here, d, path, tube = where[keep], d[keep], path[keep], tube[keep]
        if not len(here):
            break
    return np.concatenate(pts_out), np.concatenate(amp_out)
