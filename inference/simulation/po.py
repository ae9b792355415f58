"""Physical optics on a triangle mesh: the electromagnetic end of the simulator (``Scattering(physics="po")``).

What it models. Monostatic physical optics for a perfect electric conductor, far field, scalar
(co-polarised; for one bounce HH = VV and there is no cross-polarised return). A lit facet
carries the PO current, and the echo at wave vector K = 4 pi f / c r (r: unit line of sight, target
to radar) is

    s(K) = sqrt(4 pi) / lambda  sum_f |n_f . r| int_f exp(-j K . x) dS,     |s|^2 = sigma,

so a flat plate at broadside gives sigma = 4 pi A^2 / lambda^2. Each facet's integral is
closed-form (Gordon 1975, IEEE Trans. AP-23:590, written as the divided difference of exp over
the facet's vertex phases: ``triangle_integral``), exact at every aspect, with no sub-facet
sampling. A facet is lit when it faces the radar (both sides of an open sheet, the outer side of a
closed body) and a ray from it to the radar is clear (Intel Embree through ``embreex`` and
``trimesh``: a compiled BVH ray engine, tens of thousands of rays in ~20 ms on 2 cores;
``RayEngine``). Shadowing is decided at the aperture's centre.

Fast path. Facets are subdivided once to ``facet_m`` (default 0.2 m, about two resolution cells),
and each lit facet is one point source at its centroid whose complex amplitude is its exact PO
integral at 3 x 3 wave vectors of the frame's k-patch (phases relative to the centroid),
interpolated across it; the echo is then the same non-uniform FFT as the scattering-centre
physics, times f / f_c (the 1 / lambda of the PO amplitude across the band). What the
interpolation misses of each facet's integral across the patch is measured against the exact
per-sample echo (``po_echo_direct``) in BENCHMARKS.md, "Physical optics": 5 % median on the
default target with 0.2 m facets, 1 % with 0.1 m.

Options. ``roughness`` gamma adds a diffuse term per lit facet by Lambert's law,
sigma_f = gamma A_f cos^2(theta_f), with a random phase per facet and frame (blankets and panels
that are not mirrors). ``bounces`` 2 or 3 follows each lit facet's specular ray (shooting and
bouncing rays, Ling, Chou & Lee 1989, IEEE Trans. AP-37:194): a ray tube of cross-section
A_f |n_f . r| reflected at every facet it hits, each reflection multiplying by -1 (PEC), radiating
back from its last hit by aperture integration (a square aperture of the tube's cross-section,
pattern sinc x sinc about its exit direction), at the path length it travelled. Left out: edge
diffraction (PTD, the fringe currents), creeping waves, surface waves, materials other than PEC,
and the near field.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from inference.errors import ModelFileError, RadarError
from inference.simulation.radar import C_M_S, Radar, line_of_sight

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


def subdivide(mesh: Mesh, max_edge_m: float) -> Mesh:
    """Return the mesh with facets halved at their longest edge until no edge is longer than ``max_edge_m``.

    Longest-edge bisection keeps well-shaped facets well shaped (no slivers); the result is a soup
    of triangles with the original facets' orientation and sidedness.
    """
    if not max_edge_m > 0:
        raise RadarError(f"facet_m = {max_edge_m} must be positive", field="facet_m")
    tri = mesh.triangles
    side = mesh.two_sided
    done_t, done_s = [], []
    while len(tri):
        edges = np.linalg.norm(tri[:, [1, 2, 0]] - tri, axis=2)  # edge i runs from corner i to corner i+1
        longest = edges.argmax(axis=1)
        small = edges.max(axis=1) <= max_edge_m
        done_t.append(tri[small])
        done_s.append(side[small])
        tri, side, longest = tri[~small], side[~small], longest[~small]
        # rotate the corners so the longest edge runs from corner 0 to corner 1, then halve it
        order = (longest[:, None] + np.arange(3)) % 3
        t = np.take_along_axis(tri, order[:, :, None], axis=1)
        mid = 0.5 * (t[:, 0] + t[:, 1])
        tri = np.concatenate([np.stack([t[:, 0], mid, t[:, 2]], 1), np.stack([mid, t[:, 1], t[:, 2]], 1)])
        side = np.concatenate([side, side])
    tris = np.concatenate(done_t)
    faces = np.arange(3 * len(tris), dtype=np.int64).reshape(-1, 3)
    return Mesh(tris.reshape(-1, 3), faces, np.concatenate(done_s))


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


# --- the facet integral -----------------------------------------------------------------------------------


def _phi1(t: Vec) -> NDArray[np.complex128]:
    """Return (exp(j t) - 1) / (j t), stable at t = 0."""
    return np.exp(0.5j * t) * np.sinc(t / (2.0 * np.pi))


def triangle_integral(rel: Vec, k: Vec) -> NDArray[np.complex128]:
    """Return int_facet exp(-j k . x) dS for facets given by corners ``rel`` (..., 3, 3), wave vectors ``k`` (..., 3).

    Gordon's closed form as the divided difference of exp over the corner phases t_i = -k . x_i:
    2 A exp(j t_r) (phi1(j(t_q - t_r)) - phi1(j(t_p - t_r))) / (j (t_q - t_p)), with the pair (p, q)
    of the most different phases as the denominator (well conditioned), and the Taylor series
    when every phase difference is below 1e-6 rad. Exact to rounding at every aspect.
    """
    e1 = rel[..., 1, :] - rel[..., 0, :]
    e2 = rel[..., 2, :] - rel[..., 0, :]
    area = 0.5 * np.linalg.norm(np.cross(e1, e2), axis=-1)
    t = -np.einsum("...ci,...i->...c", rel, k)
    d01, d12, d20 = np.abs(t[..., 0] - t[..., 1]), np.abs(t[..., 1] - t[..., 2]), np.abs(t[..., 2] - t[..., 0])
    # reference corner r: the one not in the most different pair
    r = np.where((d12 >= d01) & (d12 >= d20), 0, np.where(d20 >= d01, 1, 2))
    p = (r + 1) % 3
    q = (r + 2) % 3
    tr = np.take_along_axis(t, r[..., None], -1)[..., 0]
    tp = np.take_along_axis(t, p[..., None], -1)[..., 0] - tr
    tq = np.take_along_axis(t, q[..., None], -1)[..., 0] - tr
    gap = tq - tp
    small = np.abs(gap) < 1e-6
    safe = np.where(small, 1.0, gap)
    dd = np.where(small, 0.5 + 1j * (tp + tq) / 6.0, (_phi1(tq) - _phi1(tp)) / (1j * safe))
    return np.asarray(2.0 * area * np.exp(1j * tr) * dd)


# --- shadowing -------------------------------------------------------------------------------------------


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


# --- the physics options ---------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class POOptions:
    """``facet_m``: facet size after subdivision; ``bounces``: 1 (PO) or 2-3 (shooting and bouncing rays);
    ``roughness``: Lambert's gamma of the diffuse term (0: mirror-smooth)."""

    facet_m: float = 0.2
    bounces: int = 1
    roughness: float = 0.0


@dataclass
class PreparedMesh:
    """A body-frame mesh subdivided for PO, its facet geometry and its ray engine (built once per mesh)."""

    mesh: Mesh
    facet_m: float
    centroids: Vec = field(init=False)
    normals: Vec = field(init=False)
    areas: Vec = field(init=False)
    rel: Vec = field(init=False)
    engine: Any = field(init=False, default=None)

    def __post_init__(self) -> None:
        self.mesh = subdivide(self.mesh, self.facet_m)
        tri = self.mesh.triangles
        cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        self.areas = 0.5 * np.linalg.norm(cross, axis=1)
        self.normals = cross / np.maximum(2.0 * self.areas, 1e-300)[:, None]
        self.centroids = tri.mean(axis=1)
        self.rel = tri - self.centroids[:, None, :]
        self.engine = RayEngine(self.mesh)


_PREPARED: dict[tuple[int, float], PreparedMesh] = {}


def prepared(mesh: Mesh, facet_m: float) -> PreparedMesh:
    """Return the mesh subdivided and ready (cached for the last two meshes: a data set reuses one)."""
    key = (id(mesh), facet_m)
    if key not in _PREPARED:
        if len(_PREPARED) >= 2:
            _PREPARED.pop(next(iter(_PREPARED)))
        _PREPARED[key] = PreparedMesh(mesh, facet_m)
    return _PREPARED[key]


def lit_facets(pm: PreparedMesh, rot: Vec, los: Vec) -> tuple[NDArray[np.int64], Vec]:
    """Return the facets the radar lights (facing it and unshadowed) and their normals turned toward it (obs frame)."""
    los_body = rot.T @ los
    cos = pm.normals @ los_body
    facing = np.where(pm.mesh.two_sided, np.abs(cos) > 1e-9, cos > 1e-9)
    idx = np.flatnonzero(facing)
    nrm = pm.normals[idx] * np.sign(cos[idx])[:, None]
    origins = pm.centroids[idx] + 1e-4 * nrm + 1e-5 * los_body
    blocked = pm.engine.first_hit(origins, np.broadcast_to(los_body, origins.shape).copy()) >= 0
    return idx[~blocked], nrm[~blocked] @ rot.T


# The fast path's nodes: the facets' integrals at K0 + (a, b) x the half-patch (range, cross-range), interpolated
# by quadratic Lagrange polynomials between them. On the default target with 0.2 m facets, 3 x 3 nodes at +-0.7
# err by 5 % (median; 20 % at most), 2 x 2 at +-0.5 by 22 % in half the time (measured before the kernels were
# compiled: 178 against 88 ms a frame; BENCHMARKS.md, "Physical optics", has today's 109 ms for 3 x 3).
NODES = (-0.7, 0.0, 0.7)


def _lagrange(nodes: tuple[float, ...], x: Vec) -> list[Vec]:
    out = []
    for i, a in enumerate(nodes):
        basis = np.ones_like(x)
        for j, b in enumerate(nodes):
            if j != i:
                basis = basis * (x - b) / (a - b)
        out.append(basis)
    return out


def po_echo(
    pm: PreparedMesh,
    rot: Vec,
    imager: Any,
    options: POOptions,
    rng: np.random.Generator,
    scale: tuple[float, float] = (1.0, 1.0),
) -> NDArray[np.complex128]:
    """Return the frame's PO echo on the Cartesian k-grid (as ``Imager.echo`` for point scatterers).

    Lit facets are point sources at their centroids; each one's amplitude across the k-patch is
    its exact integral at ``NODES`` x ``NODES`` wave vectors, interpolated (one NUFFT per node, the
    gridding shared); diffuse (``roughness``) and multi-bounce (``bounces``) terms are point sources
    too. ``scale`` stretches range and cross-range positions (the scale-error option).
    """
    from inference.simulation.radar import nufft_type1, projection_matrix

    radar = imager.radar
    los, rate = projection_matrix(radar)
    lam = radar.wavelength_m
    gain = math.sqrt(4.0 * math.pi) / lam
    nr, na = radar.n_range, radar.n_azimuth
    half_r, half_a = math.pi / radar.range_cell_m, math.pi / radar.cross_range_cell_m
    k0 = 4.0 * math.pi / lam * los
    idx, nrm = lit_facets(pm, rot, los)
    cos = np.abs(nrm @ los)
    rel = pm.rel[idx] @ rot.T
    pts = pm.centroids[idx] @ rot.T
    nodes = np.asarray(NODES, float)
    block = np.empty((len(idx), len(nodes) ** 2), np.complex128)
    from inference.simulation.kernels import node_integrals

    node_integrals(np.ascontiguousarray(rel), k0, half_r * los, half_a * rate, nodes, gain * cos, block)
    cols = list(block.T)
    extra_p, extra_a = _extra_sources(pm, rot, idx, nrm, los, lam, options, rng)
    if len(extra_p):  # point-like terms: the same amplitude at every node
        pts = np.concatenate([pts, extra_p])
        cols = [np.concatenate([c, extra_a]) for c in cols]
    pts = pts * np.array([scale[0], scale[1], 1.0]) if scale != (1.0, 1.0) else pts
    u, v = imager.pixel_coordinates(pts)
    carrier = np.exp(-1j * (k0 @ los) * (pts @ los))[:, None] * np.stack(cols, axis=1)
    spectra = nufft_type1(u, v, carrier, nr, na)
    lr = _lagrange(NODES, np.arange(-nr // 2, nr // 2) / (nr / 2))
    la = _lagrange(NODES, np.arange(-na // 2, na // 2) / (na / 2))
    echo = np.zeros((nr, na), np.complex128)
    for p, (i, j) in enumerate((i, j) for i in range(len(NODES)) for j in range(len(NODES))):
        echo += np.outer(lr[i], la[j]) * spectra[p]
    return np.asarray(echo * band_factor(radar)[:, None], np.complex128)


def po_sources(
    pm: PreparedMesh, rot: Vec, radar: Radar, options: POOptions, rng: np.random.Generator
) -> tuple[Vec, NDArray[np.complex128]]:
    """Return point sources (obs frame, m) and amplitudes (sqrt(m^2)) whose echo is the frame's PO echo at the aperture's centre.

    The one-node form of ``po_echo``, for the range-Doppler chain (``polar_echo``): each lit facet's
    exact integral at K0, plus the diffuse and multi-bounce terms.
    """
    los, _ = line_of_sight(math.radians(radar.pitch_deg), 0.0)
    lam = radar.wavelength_m
    idx, nrm = lit_facets(pm, rot, los)
    cos = np.abs(nrm @ los)
    amps = math.sqrt(4.0 * math.pi) / lam * cos * triangle_integral(pm.rel[idx] @ rot.T, 4.0 * math.pi / lam * los)
    pts = pm.centroids[idx] @ rot.T
    extra_p, extra_a = _extra_sources(pm, rot, idx, nrm, los, lam, options, rng)
    return np.concatenate([pts, extra_p]), np.concatenate([amps, extra_a]).astype(np.complex128)


def _extra_sources(
    pm: PreparedMesh,
    rot: Vec,
    idx: NDArray[np.int64],
    nrm: Vec,
    los: Vec,
    lam: float,
    options: POOptions,
    rng: np.random.Generator,
) -> tuple[Vec, NDArray[np.complex128]]:
    """The diffuse terms (Lambert's law, random phases) and the multi-bounce ray tubes, as point sources."""
    pts: list[Vec] = [np.zeros((0, 3))]
    amps: list[NDArray[np.complex128]] = [np.zeros(0, np.complex128)]
    if options.roughness > 0:
        cos = np.abs(nrm @ los)
        sigma = options.roughness * pm.areas[idx] * cos**2
        pts.append(pm.centroids[idx] @ rot.T)
        amps.append(np.sqrt(sigma) * np.exp(2j * np.pi * rng.random(len(idx))))
    if options.bounces > 1:
        p2, a2 = _bounce_sources(pm, rot, idx, nrm, los, lam, options.bounces)
        pts.append(p2)
        amps.append(a2)
    return np.concatenate(pts), np.concatenate(amps)


def _bounce_sources(
    pm: PreparedMesh, rot: Vec, idx: NDArray[np.int64], nrm: Vec, los: Vec, lam: float, bounces: int
) -> tuple[Vec, NDArray[np.complex128]]:
    """Shooting and bouncing rays from the lit facets: the tubes that hit another facet, radiating from their last hit."""
    k = 2.0 * math.pi / lam
    start = pm.centroids[idx] @ rot.T
    tube = pm.areas[idx] * np.abs(nrm @ los)  # cross-section of each tube, m^2
    d = -los + 2.0 * (nrm @ los)[:, None] * nrm  # reflected direction (incidence along -los)
    path = -(start @ los)  # path from the reference plane through the origin to the first hit
    here = start
    sign = 1.0
    pts_out, amp_out = [], []
    normals_obs = pm.normals @ rot.T
    for _ in range(bounces - 1):
        hit, where_body = pm.engine.first_hit_location((here + 1e-4 * d) @ rot, np.ascontiguousarray(d @ rot))
        ok = hit >= 0
        if not ok.any():
            break
        hit, where, d, path, tube, prev = hit[ok], where_body[ok] @ rot.T, d[ok], path[ok], tube[ok], here[ok]
        path = path + np.linalg.norm(where - prev, axis=1)
        n = normals_obs[hit]
        n = n * np.where((n * d).sum(1) > 0, -1.0, 1.0)[:, None]  # the side the ray arrives on
        closed_back = ~pm.mesh.two_sided[hit] & ((normals_obs[hit] * d).sum(1) > 0)
        d = d - 2.0 * (d * n).sum(1)[:, None] * n
        sign = -sign
        # radiate back to the radar from this hit: aperture integration over the tube's cross-section
        side = np.sqrt(tube)
        _, a1, a2 = _basis(d)
        s1, s2 = los @ a1.T, los @ a2.T
        pattern = np.sinc(k * side * s1 / np.pi) * np.sinc(k * side * s2 / np.pi) * np.clip((d @ los + 1.0) / 2.0, 0, 1)
        total = path - where @ los  # the two-way path, from the reference plane through the origin and back
        good = ~closed_back & (d @ los > 0)
        # the equivalent point: the range of that path, the cross-range of the last two hits' midpoint; its
        # phase exp(-j K . p_eq) is the path's (exp(+j k total)), so the amplitude itself is real
        mid = 0.5 * (prev + where)
        p_eq = mid + (-total / 2.0 - mid @ los)[:, None] * los
        amp = sign * math.sqrt(4.0 * math.pi) / lam * tube * pattern + 0j
        pts_out.append(p_eq[good])
        amp_out.append(amp[good])
        keep = ~closed_back
        here, d, path, tube = where[keep], d[keep], path[keep], tube[keep]
        if not len(here):
            break
    if not pts_out:
        return np.zeros((0, 3)), np.zeros(0, np.complex128)
    return np.concatenate(pts_out), np.concatenate(amp_out)


def _basis(d: Vec) -> tuple[Vec, Vec, Vec]:
    """Two unit vectors across each direction in ``d`` (N, 3)."""
    helper = np.where(np.abs(d[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    a1 = np.cross(d, helper)
    a1 /= np.linalg.norm(a1, axis=1, keepdims=True)
    return d, a1, np.cross(d, a1)


def rcs_m2(pm: PreparedMesh, rot: Vec, wavelength_m: float, bounces: int = 1) -> float:
    """Return the monostatic radar cross-section (m^2) at one wavelength, the radar along +x of the observation frame.

    Exact PO (every lit facet's closed-form integral at K = 4 pi / lambda x) plus, with
    ``bounces`` > 1, the ray tubes: what the closed-form cross sections are checked against.
    """
    los = np.array([1.0, 0.0, 0.0])
    k_vec = 4.0 * math.pi / wavelength_m * los
    idx, nrm = lit_facets(pm, rot, los)
    gain = math.sqrt(4.0 * math.pi) / wavelength_m
    total = complex(np.sum(gain * np.abs(nrm @ los) * triangle_integral(pm.mesh.triangles[idx] @ rot.T, k_vec)))
    if bounces > 1:
        pts, amps = _bounce_sources(pm, rot, idx, nrm, los, wavelength_m, bounces)
        total += complex(np.sum(amps * np.exp(-1j * (pts @ k_vec))))
    return abs(total) ** 2


def band_factor(radar: Radar) -> Vec:
    """Return f / f_c on the Cartesian k-grid's rows: the 1 / lambda of the PO amplitude across the band."""
    nr = radar.n_range
    dkx = 2.0 * math.pi / (nr * radar.range_cell_m)
    kc = 4.0 * math.pi * radar.carrier_hz / C_M_S
    return np.asarray((kc + dkx * np.arange(-nr // 2, nr // 2)) / kc)


def po_echo_direct(
    pm: PreparedMesh,
    rot: Vec,
    radar: Radar,
    chunk: int = 256,
    samples: tuple[NDArray[np.int64], NDArray[np.int64]] | None = None,
) -> NDArray[np.complex128]:
    """Return the exact PO echo on the Cartesian k-grid (the reference): every lit facet's integral at every sample.

    Each sample K gets sqrt(4 pi) |K| / (4 pi) |n . K/|K|| int exp(-j K . x) dS summed over the facets lit at
    the aperture's centre. O(F N_r N_a): seconds for a test mesh, minutes for a station. ``samples`` (rows,
    columns of the grid) evaluates only those, returned in their order.
    """
    from inference.simulation.radar import projection_matrix

    los, _ = line_of_sight(math.radians(radar.pitch_deg), 0.0)
    idx, nrm = lit_facets(pm, rot, los)
    tri = pm.mesh.triangles[idx] @ rot.T
    nr, na = radar.n_range, radar.n_azimuth
    kc = 4.0 * math.pi * radar.carrier_hz / C_M_S
    dkx = 2.0 * math.pi / (nr * radar.range_cell_m)
    dky = 2.0 * math.pi / (na * radar.cross_range_cell_m)
    a = projection_matrix(radar)
    if samples is None:
        rows, cols = (g.ravel() for g in np.meshgrid(np.arange(nr), np.arange(na), indexing="ij"))
    else:
        rows, cols = (np.asarray(g) for g in samples)
    kvec = (kc + dkx * (rows - nr // 2))[:, None] * a[0] + (dky * (cols - na // 2))[:, None] * a[1]
    kmag = np.linalg.norm(kvec, axis=1)
    out = np.zeros(len(kvec), np.complex128)
    for s in range(0, len(kvec), chunk):
        kk = kvec[s : s + chunk]
        kn = kmag[s : s + chunk]
        cos = np.abs(nrm @ (kk / kn[:, None]).T)  # (F, chunk)
        integral = triangle_integral(tri[:, None, :, :], kk[None, :, :])  # (F, chunk)
        out[s : s + chunk] = np.sqrt(4.0 * np.pi) * kn / (4.0 * np.pi) * (cos * integral).sum(axis=0)
    return out if samples is not None else out.reshape(nr, na)
