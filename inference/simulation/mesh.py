"""Triangle meshes for physical optics: the ``Mesh`` type, primitives (the built-in targets and the closed-form
tests), subdivision, and the checks an operator's mesh must pass (``checked_mesh``)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from inference.errors import ModelFileError, RadarError

Vec = NDArray[np.float64]
Faces = NDArray[np.int64]


@dataclass(frozen=True, slots=True)
class Mesh:
    """A triangle mesh in metres: ``vertices`` (V, 3), ``faces`` (F, 3) wound outward, ``two_sided`` (F,).

    Facets of closed bodies are lit from outside only; facets of open sheets (solar wings, a
    plate) from either side.
    """

    vertices: Vec
    faces: Faces
    two_sided: NDArray[np.bool_]

    @property
    def triangles(self) -> Vec:
        """Return the facets' corners, (F, 3, 3)."""
        return self.vertices[self.faces]

    def area_m2(self) -> float:
        t = self.triangles
        return float(0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1).sum())

    def shifted(self, offset: Vec) -> Mesh:
        return Mesh(self.vertices + offset, self.faces, self.two_sided)


def join(meshes: list[Mesh]) -> Mesh:
    """Return one mesh holding all of ``meshes``' facets."""
    verts, faces, sides, base = [], [], [], 0
    for m in meshes:
        verts.append(m.vertices)
        faces.append(m.faces + base)
        sides.append(m.two_sided)
        base += len(m.vertices)
    return Mesh(np.concatenate(verts), np.concatenate(faces), np.concatenate(sides))


# --- building meshes of primitives (the built-in targets, the closed-form tests) -------------------------


def orthonormal_frame(axis: Vec) -> tuple[Vec, Vec, Vec]:
    """Return the unit ``axis`` and two unit vectors across it (a right-handed frame a, u, w)."""
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    helper = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(a, helper)
    u /= np.linalg.norm(u)
    return a, u, np.cross(a, u)


def cylinder_mesh(origin: Vec, axis: Vec, radius: float, length: float, segments: int = 64, rings: int = 1) -> Mesh:
    """Return a closed circular cylinder (side and both end caps), wound outward: ``segments`` around, ``rings`` along."""
    a, u, w = orthonormal_frame(axis)
    phi = np.linspace(0.0, 2 * math.pi, segments, endpoint=False)
    ring = radius * (np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * w)
    o = np.asarray(origin, float)
    n = segments
    along = np.linspace(0.0, length, rings + 1)
    verts = np.concatenate([o + s * a + ring for s in along])
    i = np.arange(n)
    j = (i + 1) % n
    side = np.concatenate(
        [np.stack([r * n + i, r * n + j, (r + 1) * n + j], 1) for r in range(rings)]
        + [np.stack([r * n + i, (r + 1) * n + j, (r + 1) * n + i], 1) for r in range(rings)]
    )
    # each end cap: concentric rings of points about 10 cm apart, Delaunay-triangulated, the outer ring the side's own
    from scipy.spatial import Delaunay

    xy = [np.zeros((1, 2))]
    for rr in np.linspace(0.0, radius, max(2, math.ceil(radius / 0.1)) + 1)[1:-1]:
        m = max(6, math.ceil(2 * math.pi * rr / 0.1))
        ang = np.linspace(0.0, 2 * math.pi, m, endpoint=False) + 0.5 * (m % 2)
        xy.append(rr * np.stack([np.cos(ang), np.sin(ang)], 1))
    inner = np.concatenate(xy)
    outer = np.stack([np.cos(phi), np.sin(phi)], 1) * radius
    simplices = Delaunay(np.concatenate([inner, outer])).simplices
    caps = []
    for end, ring_start, flip in ((0.0, 0, True), (length, rings * n, False)):
        base = len(verts)
        verts = np.concatenate([verts, o + end * a + inner[:, :1] * u + inner[:, 1:] * w])
        index = np.concatenate([base + np.arange(len(inner)), ring_start + np.arange(n)])
        f = index[simplices]
        # wind outward: the cap at the start faces -axis, the one at the end +axis
        normal = np.cross(verts[f[:, 1]] - verts[f[:, 0]], verts[f[:, 2]] - verts[f[:, 0]]) @ a
        wrong = (normal > 0) if flip else (normal < 0)
        f[wrong] = f[wrong][:, [0, 2, 1]]
        caps.append(f)
    faces = np.concatenate([side, *caps]).astype(np.int64)
    return Mesh(verts, faces, np.zeros(len(faces), bool))


def sphere_mesh(center: Vec, radius: float, subdivisions: int = 3) -> Mesh:
    """Return a closed sphere: an icosahedron subdivided ``subdivisions`` times, its vertices on the sphere."""
    t = (1.0 + 5**0.5) / 2.0
    v = np.array(
        [[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t], [0, -1, -t], [0, 1, -t],
         [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]], float
    )  # fmt: skip
    f = np.array(
        [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4], [11, 10, 2],
         [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5], [2, 4, 11],
         [6, 2, 10], [8, 6, 7], [9, 8, 1]], np.int64
    )  # fmt: skip
    mesh = Mesh(v / np.linalg.norm(v, axis=1, keepdims=True), f, np.zeros(len(f), bool))
    for _ in range(subdivisions):
        mesh = _split4(mesh)
        mesh = Mesh(mesh.vertices / np.linalg.norm(mesh.vertices, axis=1, keepdims=True), mesh.faces, mesh.two_sided)
    return Mesh(np.asarray(center, float) + radius * mesh.vertices, mesh.faces, mesh.two_sided)


def plate_mesh(center: Vec, u_dir: Vec, v_dir: Vec, size_u: float, size_v: float) -> Mesh:
    """Return a flat rectangular plate (two triangles, lit from both sides), its normal u x v."""
    u = np.asarray(u_dir, float) / np.linalg.norm(u_dir)
    v = np.asarray(v_dir, float)
    v = v - (v @ u) * u
    v /= np.linalg.norm(v)
    c = np.asarray(center, float)
    hu, hv = size_u / 2 * u, size_v / 2 * v
    verts = np.array([c - hu - hv, c + hu - hv, c + hu + hv, c - hu + hv])
    faces = np.array([[0, 1, 2], [0, 2, 3]], np.int64)
    return Mesh(verts, faces, np.ones(2, bool))


def disc_mesh(center: Vec, normal: Vec, radius: float, segments: int = 96) -> Mesh:
    """Return a flat circular disc (a fan of ``segments`` triangles, lit from both sides), its normal ``normal``."""
    a, u, w = orthonormal_frame(normal)
    phi = np.linspace(0.0, 2 * math.pi, segments, endpoint=False)
    c = np.asarray(center, float)
    verts = np.concatenate([[c], c + radius * (np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * w)])
    i = np.arange(segments)
    faces = np.stack([np.zeros(segments, np.int64), 1 + i, 1 + (i + 1) % segments], 1)
    return Mesh(verts, faces, np.ones(segments, bool))


def box_mesh(size: Vec, center: Vec | None = None) -> Mesh:
    """Return a closed axis-aligned box of ``size`` (x, y, z), wound outward."""
    c = np.zeros(3) if center is None else np.asarray(center, float)
    corners = np.array([[i, j, k] for i in (-0.5, 0.5) for j in (-0.5, 0.5) for k in (-0.5, 0.5)]) * size + c
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    faces = np.array([t for a, b, cc, d in quads for t in ((a, b, cc), (a, cc, d))], np.int64)
    return Mesh(corners, faces, np.zeros(len(faces), bool))


def _split4(mesh: Mesh) -> Mesh:
    """Split every facet into four at its edges' midpoints (shared midpoints are shared vertices)."""
    f = mesh.faces
    edges = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    key = np.sort(edges, axis=1)
    uniq, inverse = np.unique(key, axis=0, return_inverse=True)
    mids = 0.5 * (mesh.vertices[uniq[:, 0]] + mesh.vertices[uniq[:, 1]])
    m = len(mesh.vertices) + inverse.reshape(3, -1)  # midpoint index of edge (01, 12, 20) per facet
    a, b, c = f[:, 0], f[:, 1], f[:, 2]
    ab, bc, ca = m[0], m[1], m[2]
    faces = np.concatenate([np.stack(t, 1) for t in ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))])
    return Mesh(np.concatenate([mesh.vertices, mids]), faces.astype(np.int64), np.tile(mesh.two_sided, 4))


def bisect(tri: Vec, max_edge_m: float) -> tuple[Vec, NDArray[np.int64]]:
    """Halve triangles (N, 3, 3) at their longest edge until no edge is longer than ``max_edge_m``.

    Longest-edge bisection keeps well-shaped facets well shaped (no slivers). Returns the pieces and, for
    each, the index of the triangle it came from.
    """
    parent = np.arange(len(tri))
    done_t, done_p = [np.zeros((0, 3, 3))], [np.zeros(0, np.int64)]
    while len(tri):
        edges = np.linalg.norm(tri[:, [1, 2, 0]] - tri, axis=2)  # edge i runs from corner i to corner i+1
        longest = edges.argmax(axis=1)
        small = edges.max(axis=1) <= max_edge_m
        done_t.append(tri[small])
        done_p.append(parent[small])
        tri, parent, longest = tri[~small], parent[~small], longest[~small]
        # rotate the corners so the longest edge runs from corner 0 to corner 1, then halve it
        order = (longest[:, None] + np.arange(3)) % 3
        t = np.take_along_axis(tri, order[:, :, None], axis=1)
        mid = 0.5 * (t[:, 0] + t[:, 1])
        tri = np.concatenate([np.stack([t[:, 0], mid, t[:, 2]], 1), np.stack([mid, t[:, 1], t[:, 2]], 1)])
        parent = np.concatenate([parent, parent])
    return np.concatenate(done_t), np.concatenate(done_p)


def subdivide(mesh: Mesh, max_edge_m: float) -> Mesh:
    """Return the mesh with facets halved at their longest edge until no edge is longer than ``max_edge_m``
    (``bisect``): a soup of triangles with the original facets' orientation and sidedness."""
    if not max_edge_m > 0:
        raise RadarError(f"facet_m = {max_edge_m} must be positive", field="facet_m")
    tris, parent = bisect(mesh.triangles, max_edge_m)
    faces = np.arange(3 * len(tris), dtype=np.int64).reshape(-1, 3)
    return Mesh(tris.reshape(-1, 3), faces, mesh.two_sided[parent])


# --- checking an operator's mesh --------------------------------------------------------------------------


def checked_mesh(vertices: Vec, faces: Faces, name: str) -> tuple[Mesh, list[str]]:
    """Return the mesh fit for physical optics and what was done to it; ModelFileError for what cannot be used.

    Refused: no faces, faces whose corners coincide (all of them), edges shared by more than two
    faces (non-manifold: no inside and outside). Closed bodies wound inside-out (negative volume)
    are turned the right way out, and bodies whose winding is inconsistent are rewound (both safe:
    a closed body has one outside); open sheets are lit from both sides.
    """
    if len(faces) == 0:
        raise ModelFileError(f"{name}: the mesh has no faces; physical optics needs facets (a surface)", field="model")
    tri = vertices[faces]
    area2 = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    keep = area2 > 1e-12 * max(1.0, float(np.abs(vertices).max()) ** 2)
    if not keep.any():
        raise ModelFileError(f"{name}: every face is degenerate (zero area)", field="model")
    faces = faces[keep]
    key = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    _, counts = np.unique(key, axis=0, return_counts=True)
    if (counts > 2).any():
        raise ModelFileError(
            f"{name}: non-manifold mesh: {int((counts > 2).sum())} edges are shared by more than two faces, "
            "so the surface has no single inside and outside; split it into separate bodies",
            field="model",
        )
    import trimesh

    notes: list[str] = []
    if (~keep).any():
        notes.append(f"dropped {int((~keep).sum())} degenerate faces")
    tm = trimesh.Trimesh(vertices, faces, process=False)
    parts: list[Mesh] = []
    for body in tm.split(only_watertight=False):
        if body.is_watertight:
            if not body.is_winding_consistent:
                trimesh.repair.fix_winding(body)  # type: ignore[no-untyped-call]
                notes.append("rewound a closed body whose facets were wound inconsistently")
            if body.volume < 0:
                body.invert()
                notes.append("turned an inside-out closed body the right way out")
            parts.append(
                Mesh(
                    np.asarray(body.vertices, float), np.asarray(body.faces, np.int64), np.zeros(len(body.faces), bool)
                )
            )
        else:
            parts.append(
                Mesh(np.asarray(body.vertices, float), np.asarray(body.faces, np.int64), np.ones(len(body.faces), bool))
            )
    return join(parts), notes


# --- rays on a mesh -------------------------------------------------------------------------------------------


class RayEngine:
    """First hits of rays on a mesh, by Intel Embree (``embreex``) through ``trimesh``; built once per mesh."""

    def __init__(self, mesh: Mesh) -> None:
        try:
            import trimesh
            from trimesh.ray.ray_pyembree import RayMeshIntersector
        except ImportError as exc:  # pragma: no cover - the dependencies are installed with the project
            raise RadarError(
                f"physical optics needs a ray engine (pip install embreex trimesh): {exc}", field="physics"
            ) from None
        self._tm = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
        self._rays = RayMeshIntersector(self._tm)

    def first_hit(self, origins: Vec, directions: Vec) -> NDArray[np.int64]:
        """Return the index of the first facet each ray hits, -1 where it hits none."""
        if len(origins) == 0:
            return np.zeros(0, np.int64)
        return np.asarray(self._rays.intersects_first(origins, directions), np.int64)

    def first_hit_location(self, origins: Vec, directions: Vec) -> tuple[NDArray[np.int64], Vec]:
        """Return the first facet hit by each ray (-1: none) and where (NaN where none)."""
        idx = self.first_hit(origins, directions)
        where = np.full((len(origins), 3), np.nan)
        hit = idx >= 0
        if hit.any():
            tri = self._tm.triangles[idx[hit]]
            n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
            o, d = origins[hit], directions[hit]
            s = np.einsum("ij,ij->i", tri[:, 0] - o, n) / np.einsum("ij,ij->i", d, n)
            where[hit] = o + s[:, None] * d
        return idx, where
