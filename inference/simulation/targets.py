"""Target models for the ISAR simulator: surface points (for labels) and scattering centres.

A model is two point sets in its body frame (metres, centred on the centroid):
``surface`` samples the skin densely (the label is its projection), and the
scatterers sample it coarsely, each with an outward normal and a kind that sets how
its echo depends on aspect (see ``inference.simulation.scene.scatterer_amplitudes``).

The default is a compact, asymmetric Tiangong-like station; ``inference.simulation.meshes`` reads an
operator's own OBJ or PLY mesh, or a PLY point cloud.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from inference.errors import ModelFileError
from inference.simulation.mesh import Mesh, box_mesh, cylinder_mesh, join, orthonormal_frame, plate_mesh, sphere_mesh

Vec = NDArray[np.float64]

# Scatterer kinds.
FLAT = 0  # flat plate facet: specular flash when its normal meets the line of sight
CURVED = 1  # cylinder or sphere skin: specular line where the normal meets the line of sight
EDGE = 2  # rims, panel edges, corners: weak, nearly isotropic
ISOTROPIC = 3  # points without normals (point clouds)


@dataclass(frozen=True, slots=True)
class TargetModel:
    """A target in its body frame: ``surface`` (N, 3), ``scatterers`` (M, 3), ``normals`` (M, 3), ``kinds`` (M,)."""

    name: str
    surface: Vec
    scatterers: Vec
    normals: Vec
    kinds: NDArray[np.int8]
    description: str = ""
    mesh: Mesh | None = None  # the skin as triangles (physical optics); None for a point cloud

    @property
    def radius_m(self) -> float:
        """Return the largest distance of the skin from the body origin (the centroid)."""
        return float(np.linalg.norm(self.surface, axis=1).max())

    @property
    def mirror_planes(self) -> list[str]:
        """Return the body planes the surface is (nearly) symmetric about: a frame cannot tell mirrored attitudes apart.

        A plane counts when 95 % of the mirrored surface lies within 15 cm of the surface; the
        near-symmetries below that, with their strength, are ``symmetries()``.
        """
        tree = _kd(self.surface)
        probe = self.surface[:: max(1, len(self.surface) // 2000)]
        return [
            name for axis, name in enumerate(PLANES) if np.percentile(_mirror_gaps(tree, probe, axis, 0.0), 95) < 0.15
        ]

    def symmetries(self, tolerance_m: float = 0.15) -> list[dict[str, Any]]:
        """How nearly the surface is symmetric about each body plane (yz, xz, xy) and the best plane parallel to it.

        For each plane through the centroid: ``share_within`` of the mirrored surface points within
        ``tolerance_m`` of the surface (1.0: an exact mirror plane) and ``p95_m``, the 95th
        percentile of their distances. ``offset_m`` and ``offset_share_within`` are the same for the
        parallel plane (searched in 2 cm steps within 1 m) that the surface is most symmetric about:
        a hull symmetric about a plane a little off its centroid is still a near-mirror ambiguity
        for a frame that sees it across that plane, even when it is not an exact mirror plane.
        """
        tree = _kd(self.surface)
        probe = self.surface[:: max(1, len(self.surface) // 2000)]
        out = []
        for axis, name in enumerate(PLANES):

            def share(c: float, axis: int = axis, points: Vec = probe) -> tuple[float, float]:
                """The share within tolerance, then (among equal shares) the smaller mean gap."""
                gaps = _mirror_gaps(tree, points, axis, c, bound_m=4.0 * tolerance_m)
                return float(np.mean(gaps <= tolerance_m)), -float(gaps.mean())

            # 10 cm steps on a quarter of the probe points, then 2 cm steps about the best on all of them.
            coarse = max(np.arange(-1.0, 1.0 + 1e-9, 0.1), key=lambda c: share(c, points=probe[::4]))
            best = max(np.clip(coarse + np.arange(-0.1, 0.1 + 1e-9, 0.02), -1.0, 1.0), key=share)
            gaps = _mirror_gaps(tree, probe, axis, 0.0)
            out.append(
                {
                    "plane": name,
                    "tolerance_m": tolerance_m,
                    "share_within": round(float(np.mean(gaps <= tolerance_m)), 4),
                    "p95_m": round(float(np.percentile(gaps, 95)), 4),
                    "offset_m": round(float(best), 2) + 0.0,  # (no -0.0)
                    "offset_share_within": round(share(best)[0], 4),
                }
            )
        return out


PLANES = ("yz", "xz", "xy")


def _mirror_gaps(tree: Any, probe: Vec, axis: int, offset_m: float, bound_m: float = np.inf) -> Vec:
    """Distances from ``probe`` points mirrored through the plane ``axis = offset_m`` to the surface (``tree``).

    With ``bound_m`` the search stops there (far points are slow to search) and farther gaps read as ``bound_m``.
    """
    mirrored = probe.copy()
    mirrored[:, axis] = 2.0 * offset_m - mirrored[:, axis]
    d, _ = tree.query(mirrored, distance_upper_bound=bound_m)
    return np.minimum(np.asarray(d), bound_m)


def _kd(points: Vec):  # type: ignore[no-untyped-def]
    from scipy.spatial import cKDTree

    return cKDTree(points)


def _orthonormal(axis: Vec) -> tuple[Vec, Vec]:
    return orthonormal_frame(axis)[1:]


def surface_normals(points: Vec, k: int = 12) -> Vec:
    """Return each point's unit normal (sign-free) from the principal axes of its ``k`` nearest neighbours."""
    from scipy.spatial import cKDTree

    _, idx = cKDTree(points).query(points, k=min(k, len(points)))
    nb = points[idx] - points[idx].mean(axis=1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", nb, nb)
    return np.asarray(np.linalg.eigh(cov)[1][:, :, 0])


def cylinder(origin: Vec, axis: Vec, radius: float, length: float, spacing: float) -> tuple[Vec, Vec, Vec, Vec]:
    """Sample a cylinder's side: returns skin points, skin normals, rim points, rim normals."""
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    u, w = _orthonormal(a)
    n_len = max(2, int(math.ceil(length / spacing)) + 1)
    n_phi = max(8, int(math.ceil(2 * math.pi * radius / spacing)))
    s = np.linspace(0.0, length, n_len)
    phi = np.linspace(0.0, 2 * math.pi, n_phi, endpoint=False)
    radial = np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * w  # (n_phi, 3)
    pts = origin + s[:, None, None] * a + radius * radial[None, :, :]
    normals = np.broadcast_to(radial[None], pts.shape)
    rims = np.concatenate([origin + radius * radial, origin + length * a + radius * radial])
    rim_normals = np.concatenate([-a + radial, a + radial])
    rim_normals /= np.linalg.norm(rim_normals, axis=1, keepdims=True)
    return pts.reshape(-1, 3), normals.reshape(-1, 3), rims, rim_normals


def disc(center: Vec, normal: Vec, radius: float, spacing: float) -> tuple[Vec, Vec]:
    """Sample a flat disc (an end cap)."""
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    u, w = _orthonormal(n)
    g = np.arange(-radius, radius + spacing / 2, spacing)
    x, y = np.meshgrid(g, g)
    keep = x**2 + y**2 <= radius**2
    pts = center + x[keep][:, None] * u + y[keep][:, None] * w
    return pts, np.broadcast_to(n, pts.shape).copy()


def sphere(center: Vec, radius: float, spacing: float) -> tuple[Vec, Vec]:
    """Sample a sphere by a Fibonacci lattice."""
    n = max(20, int(4 * math.pi * radius**2 / spacing**2))
    k = np.arange(n) + 0.5
    polar = np.arccos(1 - 2 * k / n)
    az = math.pi * (1 + 5**0.5) * k
    normals = np.stack([np.cos(az) * np.sin(polar), np.sin(az) * np.sin(polar), np.cos(polar)], axis=1)
    return center + radius * normals, normals


def plate(center: Vec, u_dir: Vec, v_dir: Vec, size_u: float, size_v: float, spacing: float) -> tuple[Vec, Vec, Vec]:
    """Sample a rectangular plate: returns face points, the face normal per point, and perimeter points."""
    u = np.asarray(u_dir, float) / np.linalg.norm(u_dir)
    v = np.asarray(v_dir, float)
    v = v - (v @ u) * u
    v /= np.linalg.norm(v)
    gu = np.linspace(-size_u / 2, size_u / 2, max(2, int(math.ceil(size_u / spacing)) + 1))
    gv = np.linspace(-size_v / 2, size_v / 2, max(2, int(math.ceil(size_v / spacing)) + 1))
    a, b = np.meshgrid(gu, gv, indexing="ij")
    pts = center + a.reshape(-1, 1) * u + b.reshape(-1, 1) * v
    edge = (np.abs(a) == gu[-1]) | (np.abs(b) == gv[-1])
    normal = np.cross(u, v)
    return pts[~edge.ravel()], np.broadcast_to(normal, (int((~edge).sum()), 3)).copy(), pts[edge.ravel()]


def _tilted(axis_u: Vec, axis_v: Vec, tilt_deg: float) -> tuple[Vec, Vec]:
    """Turn a plate's width direction ``axis_v`` about its length direction ``axis_u``."""
    u = axis_u / np.linalg.norm(axis_u)
    v = axis_v / np.linalg.norm(axis_v)
    t = math.radians(tilt_deg)
    return u, v * math.cos(t) + np.cross(u, v) * math.sin(t)


def _assembled(
    name: str, parts_sc: list[tuple[Vec, Vec, int]], parts_surf: list[Vec], parts_mesh: list[Mesh], description: str
) -> TargetModel:
    """Join a built target's parts (scattering centres, skin, facets) and centre it on its skin's centroid."""
    sc = np.concatenate([p for p, _, _ in parts_sc])
    normals = np.concatenate([n for _, n, _ in parts_sc])
    kinds = np.concatenate([np.full(len(p), k, np.int8) for p, _, k in parts_sc])
    surface = np.concatenate(parts_surf)
    centroid = surface.mean(axis=0)
    mesh = join(parts_mesh).shifted(-centroid)
    return TargetModel(name, surface - centroid, sc - centroid, normals, kinds, description, mesh)


def _segments(radius: float) -> int:
    """Facets around a cylinder: strips 10 cm wide (17 cm along it), so neighbouring strips' specular lobes overlap."""
    return max(24, math.ceil(2 * math.pi * radius / 0.1))


def tiangong_like(scatterer_spacing_m: float = 0.3, surface_spacing_m: float = 0.08) -> TargetModel:
    """Build the default target: a compact, deliberately asymmetric Tiangong-like station.

    Modelled on the Tiangong station's layout (Tianhe core, node, one laboratory
    module, a docked cargo ship, solar wings of unequal size and angle) but shortened
    so every attitude fits the 24 m x 29 m frame of the paper's radar:

    * core module: 8.5 m at 4.2 m diameter, then 3.5 m at 2.8 m diameter (along +x);
    * node: a 2.8 m sphere at the core's forward end;
    * laboratory module: 7 m at 4.2 m diameter on the node's +y port only;
    * cargo ship: 3.5 m at 3.2 m diameter docked at the core's aft end;
    * wings: on the core, +z 5.5 m x 2.2 m turned 20 deg and -z 4.5 m x 2.2 m turned
      -35 deg; on the laboratory, +z 4 m x 1.8 m turned 10 deg.

    The result has no mirror plane (see ``TargetModel.mirror_planes``), so no two
    attitudes within +-45 deg give the same frame.
    """
    s_sc, s_surf = scatterer_spacing_m, surface_spacing_m
    ex, ey, ez = np.eye(3)
    parts_sc: list[tuple[Vec, Vec, int]] = []
    parts_surf: list[Vec] = []
    parts_mesh: list[Mesh] = []

    def add_cylinder(origin: Vec, axis: Vec, radius: float, length: float, caps: tuple[bool, bool]) -> None:
        parts_mesh.append(
            cylinder_mesh(origin, axis, radius, length, _segments(radius), max(1, math.ceil(length / 0.17)))
        )
        p, n, rim, rim_n = cylinder(origin, axis, radius, length, s_sc)
        parts_sc.extend([(p, n, CURVED), (rim, rim_n, EDGE)])
        parts_surf.append(cylinder(origin, axis, radius, length, s_surf)[0])
        a = axis / np.linalg.norm(axis)
        for end, keep in ((0.0, caps[0]), (length, caps[1])):
            if keep:
                c = origin + end * a
                normal = -a if end == 0.0 else a
                parts_sc.append((*disc(c, normal, radius, s_sc), FLAT))
                parts_surf.append(disc(c, normal, radius, s_surf)[0])

    def add_plate(center: Vec, u: Vec, v: Vec, su: float, sv: float, tilt: float) -> None:
        u, v = _tilted(u, v, tilt)
        parts_mesh.append(plate_mesh(center, u, v, su, sv))
        face, normals, edge = plate(center, u, v, su, sv, s_sc)
        parts_sc.extend([(face, normals, FLAT), (edge, np.broadcast_to(normals[0], edge.shape).copy(), EDGE)])
        parts_surf.append(plate(center, u, v, su, sv, s_surf)[0])
        parts_surf.append(plate(center, u, v, su, sv, s_surf)[2])

    origin = np.zeros(3)
    add_cylinder(origin + [-4.5, 0, 0], ex, 2.1, 8.5, (True, False))
    add_cylinder(origin + [4.0, 0, 0], ex, 1.4, 3.5, (False, False))
    node = np.array([8.7, 0.0, 0.0])
    p, n = sphere(node, 1.4, s_sc)
    parts_mesh.append(sphere_mesh(node, 1.4, 3))
    parts_sc.append((p, n, CURVED))
    parts_surf.append(sphere(node, 1.4, s_surf)[0])
    add_cylinder(node + [0, 1.2, 0], ey, 2.1, 7.0, (False, True))
    add_cylinder(origin + [-8.0, 0, 0], ex, 1.6, 3.5, (True, False))
    add_plate(origin + [-1.5, 0, 2.1 + 2.75], ez, ex, 5.5, 2.2, 20.0)
    add_plate(origin + [-1.5, 0, -2.1 - 2.25], ez, ex, 4.5, 2.2, -35.0)
    add_plate(node + [0, 6.0, 2.1 + 2.0], ez, ey, 4.0, 1.8, 10.0)

    return _assembled(
        "tiangong-like",
        parts_sc,
        parts_surf,
        parts_mesh,
        "compact asymmetric Tiangong-like station (inference/simulation/targets.py: tiangong_like)",
    )


def comsat_like(scatterer_spacing_m: float = 0.3, surface_spacing_m: float = 0.08) -> TargetModel:
    """Build a second target, unlike the default: a box-wing communications satellite.

    A 3.2 m x 2.4 m x 2.6 m bus (its long side along x), two solar wings of 7 m x 2.2 m
    on yokes along +-y (the +y wing turned 25 deg about its length, the -y wing
    -10 deg), a 2.6 m dish on the bus's +z face (a shallow cylinder standing in for it)
    and a 1.2 m thruster cylinder at -x. No network was trained on it: it is the
    catalogue's "another satellite" and the target of the no-network path's measurements.
    """
    s_sc, s_surf = scatterer_spacing_m, surface_spacing_m
    ex, ey, ez = np.eye(3)
    parts_sc: list[tuple[Vec, Vec, int]] = []
    parts_surf: list[Vec] = []
    parts_mesh: list[Mesh] = []

    def add_plate(center: Vec, u: Vec, v: Vec, su: float, sv: float, tilt: float = 0.0, mesh: bool = True) -> None:
        u, v = _tilted(u, v, tilt)
        if mesh:
            parts_mesh.append(plate_mesh(center, u, v, su, sv))
        face, normals, edge = plate(center, u, v, su, sv, s_sc)
        parts_sc.extend([(face, normals, FLAT), (edge, np.broadcast_to(normals[0], edge.shape).copy(), EDGE)])
        fine = plate(center, u, v, su, sv, s_surf)
        parts_surf.extend([fine[0], fine[2]])

    def add_cylinder(origin: Vec, axis: Vec, radius: float, length: float) -> None:
        parts_mesh.append(
            cylinder_mesh(origin, axis, radius, length, _segments(radius), max(1, math.ceil(length / 0.17)))
        )
        p, n, rim, rim_n = cylinder(origin, axis, radius, length, s_sc)
        parts_sc.extend([(p, n, CURVED), (rim, rim_n, EDGE)])
        parts_surf.append(cylinder(origin, axis, radius, length, s_surf)[0])
        a = axis / np.linalg.norm(axis)
        for end, normal in ((origin, -a), (origin + length * a, a)):
            parts_sc.append((*disc(end, normal, radius, s_sc), FLAT))
            parts_surf.append(disc(end, normal, radius, s_surf)[0])

    lx, ly, lz = 3.2, 2.4, 2.6
    for axis, size, (u, v, su, sv) in (
        (ex, lx, (ey, ez, ly, lz)),
        (ey, ly, (ex, ez, lx, lz)),
        (ez, lz, (ex, ey, lx, ly)),
    ):
        for sign in (1.0, -1.0):
            add_plate(sign * axis * size / 2, u, v, su, sv, mesh=False)
    parts_mesh.append(box_mesh(np.array([lx, ly, lz])))
    add_plate(np.array([0.0, ly / 2 + 0.6 + 3.5, 0.0]), ey, ex, 7.0, 2.2, 25.0)
    add_plate(np.array([0.0, -ly / 2 - 0.6 - 3.5, 0.0]), ey, ex, 7.0, 2.2, -10.0)
    for sign in (1.0, -1.0):  # the yokes: rods from the bus to the wings
        add_cylinder(np.array([0.0, sign * ly / 2, 0.0]), sign * ey, 0.1, 0.6)
    add_cylinder(np.array([0.4, 0.0, lz / 2]), ez, 1.3, 0.35)
    add_cylinder(np.array([-lx / 2 - 1.2, 0.0, 0.0]), ex, 0.5, 1.2)
    return _assembled(
        "comsat-like",
        parts_sc,
        parts_surf,
        parts_mesh,
        "box-wing communications satellite (inference/simulation/targets.py: comsat_like)",
    )


BUILTIN_TARGETS = {"tiangong-like": tiangong_like, "comsat-like": comsat_like}
DEFAULT_TARGET = "tiangong-like"


def builtin_target(name: str) -> TargetModel:
    """Return a built-in target by name (``BUILTIN_TARGETS``); ModelFileError names the choices otherwise."""
    if name not in BUILTIN_TARGETS:
        raise ModelFileError(
            f"unknown target {name!r}: the built-in targets are {', '.join(sorted(BUILTIN_TARGETS))}", field="target"
        )
    return BUILTIN_TARGETS[name]()
