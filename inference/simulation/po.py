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
``RayEngine``), decided at each of the three cross-range nodes of the aperture (``lit_across``).

Fast path (``po_echo``). Facets are subdivided once to ``facet_m`` (default 0.2 m), which sets the
resolution of shadows. Each lit facet's exact integral is written, by the divergence theorem on its
plane, as sources on its edges (``edge_sources``): a regular edge is two corner sources whose
amplitudes are smooth in K, evaluated at 3 x 3 wave vectors of the frame's k-patch and interpolated
across it, so the corners coplanar neighbours share cancel as they do in the integral; an edge nearly
at one range is Gauss-Legendre points along it; near-specular facets are split into pieces of half a
resolution cell with their exact node integrals (``specular_sources``). Obliquity is taken per node.
The echo is the same non-uniform FFT as the scattering-centre physics, per node, times |K| / k_c.
Against closed forms and the exact per-sample echo (``po_echo_direct``): BENCHMARKS.md, "Physical
optics".

Options. ``roughness`` gamma adds a diffuse term per lit facet by Lambert's law,
sigma_f = gamma A_f cos^2(theta_f), with a random phase per facet and frame (blankets and panels
that are not mirrors). ``bounces`` 2 or 3 follows each lit facet's specular ray (shooting and
bouncing rays, Ling, Chou & Lee 1989, IEEE Trans. AP-37:194): a ray tube of cross-section
A_f |n_f . r| reflected at every facet it hits, each reflection multiplying by -1 (PEC), radiating
back from its last hit by aperture integration where the exit sees the radar
(``inference.simulation.sbr``). Left out: edge diffraction (PTD, the fringe currents), creeping
waves, surface waves, materials other than PEC, and the near field.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from inference.simulation.mesh import Mesh, RayEngine, bisect, subdivide
from inference.simulation.radar import C_M_S, Radar, line_of_sight, nufft_type1, projection_matrix
from inference.simulation.sbr import bounce_sources, launch_tubes

Vec = NDArray[np.float64]


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


# --- the physics options ---------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class POOptions:
    """``facet_m``: facet size after subdivision (the resolution of shadows and of the lit set); ``bounces``: 1 (PO)
    or 2-3 (shooting and bouncing rays); ``roughness``: Lambert's gamma of the diffuse term (0: mirror-smooth);
    ``tube_m``: the largest ray tube of the bounces (``inference.simulation.sbr``)."""

    facet_m: float = 0.2
    bounces: int = 1
    roughness: float = 0.0
    tube_m: float = 0.05


@dataclass
class PreparedMesh:
    """A body-frame mesh subdivided for PO, its facet geometry and its ray engine (built once per mesh).

    ``vertex_id`` numbers the facets' corners by position (corners shared by facets share a number), so the
    echo's corner sources of neighbouring facets add up before they are imaged.
    """

    mesh: Mesh
    facet_m: float
    centroids: Vec = field(init=False)
    normals: Vec = field(init=False)
    areas: Vec = field(init=False)
    rel: Vec = field(init=False)
    vertex_id: NDArray[np.int64] = field(init=False)
    unique_vertices: Vec = field(init=False)
    engine: Any = field(init=False, default=None)

    def __post_init__(self) -> None:
        self.mesh = subdivide(self.mesh, self.facet_m)
        tri = self.mesh.triangles
        cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        self.areas = 0.5 * np.linalg.norm(cross, axis=1)
        self.normals = cross / np.maximum(2.0 * self.areas, 1e-300)[:, None]
        self.centroids = tri.mean(axis=1)
        self.rel = tri - self.centroids[:, None, :]
        uniq, inverse = np.unique(np.round(tri.reshape(-1, 3), 7), axis=0, return_inverse=True)
        self.unique_vertices = uniq
        self.vertex_id = inverse.reshape(-1, 3).astype(np.int64)
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


# --- which facets the radar lights ----------------------------------------------------------------------


def lit_across(pm: PreparedMesh, rot: Vec, dirs: Vec) -> tuple[NDArray[np.int64], Vec, NDArray[np.bool_]]:
    """Return the facets lit along any of ``dirs`` (D, 3; obs frame, toward the radar), their normals and where lit.

    A facet is lit along a direction when it faces it (either side of an open sheet, the outside of a closed
    body) and a ray from it toward the radar is clear. The normals (obs frame) are turned toward the middle
    direction (an open sheet keeps that side across the aperture, so its obliquity changes sign smoothly where
    the radar crosses its plane); ``lit`` is (F, D).
    """
    body = np.atleast_2d(dirs) @ rot
    cos = pm.normals @ body.T
    facing = np.where(pm.mesh.two_sided[:, None], np.abs(cos) > 1e-9, cos > 1e-9)
    cand = np.flatnonzero(facing.any(axis=1))
    lit = np.zeros((len(cand), len(body)), bool)
    for k, d in enumerate(body):
        sel = np.flatnonzero(facing[cand, k])
        f = cand[sel]
        side = np.sign(cos[f, k])[:, None]
        origins = pm.centroids[f] + 1e-4 * side * pm.normals[f] + 1e-5 * d
        lit[sel, k] = pm.engine.first_hit(origins, np.ascontiguousarray(np.broadcast_to(d, origins.shape))) < 0
    keep = lit.any(axis=1)
    idx, lit = cand[keep], lit[keep]
    mid = cos[idx, len(body) // 2]
    side = np.where(mid != 0, np.sign(mid), np.sign(cos[idx].sum(axis=1)))
    side = np.where(pm.mesh.two_sided[idx] & (side != 0), side, 1.0)
    return idx, (pm.normals[idx] * side[:, None]) @ rot.T, lit


def lit_facets(pm: PreparedMesh, rot: Vec, los: Vec) -> tuple[NDArray[np.int64], Vec]:
    """Return the facets the radar lights along ``los`` and their normals turned toward it (obs frame)."""
    idx, nrm, _ = lit_across(pm, rot, np.asarray(los, float)[None])
    return idx, nrm


# --- the fast echo: corner and edge sources ---------------------------------------------------------------

# The fast path's nodes: the sources' amplitudes at K0 + (a, b) x the half-patch (range, cross-range),
# interpolated by quadratic Lagrange polynomials between them.
NODES = (-0.7, 0.0, 0.7)
# An edge is singular (its corner terms blow up and cancel) when its phase K0 . e is under KAPPA_EDGE times its
# swing across the patch; a facet is near specular when its tangential wave number at K0 is under KAPPA_SPECULAR
# times the patch's half-width. Measured on plates and a cylinder at 0.5-20 deg off specular (64 x 64 frames,
# against po_echo_direct): 0.06-0.6 % windowed error with these; KAPPA_SPECULAR 3-6 let the rational factor's
# interpolation err by 2-28 %, and KAPPA_EDGE 3, 4 and 6 measured alike (4: fewer line points than 6).
KAPPA_EDGE = 4.0
KAPPA_SPECULAR = 2.0
# Open-sheet planes that the line of sight crosses during the aperture imaged each with its own |n . K| (po_echo).
CROSSING_PLANES = 4


def _lagrange(nodes: tuple[float, ...], x: Vec) -> list[Vec]:
    out = []
    for i, a in enumerate(nodes):
        basis = np.ones_like(x)
        for j, b in enumerate(nodes):
            if j != i:
                basis = basis * (x - b) / (a - b)
        out.append(basis)
    return out


def _gauss_points(n: int) -> tuple[Vec, Vec]:
    x, w = np.polynomial.legendre.leggauss(n)
    return (x + 1.0) / 2.0, w / 2.0


def edge_sources(
    tri: Vec, normal: Vec, amp: NDArray[Any], kn: Vec, swing: Vec, ids: NDArray[np.int64], positions: Vec
) -> tuple[NDArray[np.int64], NDArray[np.complex128], Vec, NDArray[np.complex128]]:
    """Facets' integrals as sources on their edges (Gordon 1975): exact for every facet that is not near specular.

    By the divergence theorem on the facet's plane, int_f exp(-j K.x) dS = sum over edges m of
    j (K_t . nu_m) / |K_t|^2 x int_edge exp(-j K.x) dl (K_t: K along the facet, nu_m: the edge's outward normal
    in it). An edge whose phase K . e stays well away from zero across the patch is two sources at its ends,
    +-L / (j K . e) times that factor: smooth in K, so interpolating the nodes' values is accurate, and the terms
    of corners shared by coplanar facets cancel node by node, hence everywhere. A singular edge (nearly at one
    range) is its line integral by Gauss-Legendre points along it. ``tri``: (F, 3, 3) obs frame; ``amp``: (F, P)
    the per-node weights (gain, obliquity, lit); ``kn``: (P, 3) node wave vectors; ``swing``: (2, 3) the
    patch's half-widths along range and cross-range as vectors. Returns the corner sources' coefficients
    summed per corner id (the ids used, ``ids`` being (F, 3), and their (U, P) coefficients), then the singular
    edges' points (N, 3) and their (N, P) coefficients.
    """
    k0 = kn[len(kn) // 2]
    k2 = (kn * kn).sum(axis=1)
    corner = np.zeros((len(tri), 3, len(kn)), np.complex128)
    sing: list[tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.complex128]]] = []
    kt2 = k2[None, :] - (normal @ kn.T) ** 2  # |K_t|^2 along each facet, (F, P)
    for m in range(3):
        a, b = tri[:, m], tri[:, (m + 1) % 3]
        e = b - a
        length = np.linalg.norm(e, axis=1)
        nu = np.cross(e, normal) / length[:, None]
        factor = amp * 1j * (nu @ kn.T) / kt2  # (F, P)
        swing_e = np.abs(e @ swing[0]) + np.abs(e @ swing[1])
        regular = np.abs(e @ k0) > KAPPA_EDGE * swing_e
        r = np.flatnonzero(regular)
        c = factor[r] * length[r, None] / (1j * (e[r] @ kn.T))
        corner[r, m] += c
        corner[r, (m + 1) % 3] -= c
        s = np.flatnonzero(~regular)
        sing.append((ids[s, m], ids[s, (m + 1) % 3], factor[s] * length[s, None]))
    used, merged = _sum_by_key(ids.reshape(-1), corner.reshape(-1, len(kn)))
    line_pts, line_cols = _line_sources(sing, positions, kn, swing)
    return used, merged, line_pts, line_cols


def _sum_by_key(
    keys: NDArray[np.int64], coef: NDArray[np.complex128]
) -> tuple[NDArray[np.int64], NDArray[np.complex128]]:
    """Sum the rows of ``coef`` (N, P) that share a key: the distinct keys and their sums."""
    used, inverse = np.unique(keys, return_inverse=True)
    inverse = inverse.ravel()
    out = np.empty((len(used), coef.shape[1]), np.complex128)
    for p in range(coef.shape[1]):
        out[:, p] = np.bincount(inverse, coef[:, p].real, len(used)) + 1j * np.bincount(
            inverse, coef[:, p].imag, len(used)
        )
    return used, out


_BASE_T, _BASE_W = (np.polynomial.legendre.leggauss(48)[0] + 1.0) / 2.0, np.polynomial.legendre.leggauss(48)[1] / 2.0


def _line_sources(
    sing: list[tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.complex128]]],
    positions: Vec,
    kn: Vec,
    swing: Vec,
) -> tuple[Vec, NDArray[np.complex128]]:
    """Singular edges' line integrals int_0^1 exp(-j K . (a + s e)) ds as points along them (obs frame).

    An edge shared by two facets is one set of points (the line integral does not depend on the edge's
    direction), its facets' factors summed. The points are Gauss-Legendre points for the phase's swing
    across the patch only; the edge's own phase at K0 (up to KAPPA_EDGE times that swing) goes into
    product-integration weights, exp(j w0 s_q) int exp(-j w0 s) l_q(s) ds, l_q the points' Lagrange basis.
    """
    lo = np.concatenate([np.minimum(i, j) for i, j, _ in sing])
    hi = np.concatenate([np.maximum(i, j) for i, j, _ in sing])
    if not len(lo):
        return np.zeros((0, 3)), np.zeros((0, len(kn)), np.complex128)
    coef = np.concatenate([c for _, _, c in sing])
    keys, summed = _sum_by_key(lo * len(positions) + hi, coef)
    a = positions[keys // len(positions)]
    e = positions[keys % len(positions)] - a
    w0 = e @ kn[len(kn) // 2]
    counts = np.ceil((np.abs(e @ swing[0]) + np.abs(e @ swing[1])) / 3.0).astype(int) + 4
    pts, cols = [], []
    for n in np.unique(counts):
        g = np.flatnonzero(counts == n)
        t, _ = _gauss_points(int(n))
        basis = np.stack(_lagrange(tuple(t), _BASE_T))  # (n, base)
        weights = (np.exp(-1j * w0[g, None] * _BASE_T[None, :]) * _BASE_W) @ basis.T  # (E, n)
        weights *= np.exp(1j * w0[g, None] * t[None, :])
        pts.append((a[g, None, :] + t[None, :, None] * e[g, None, :]).reshape(-1, 3))
        cols.append((summed[g][:, None, :] * weights[:, :, None]).reshape(-1, len(kn)))
    return np.concatenate(pts), np.concatenate(cols)


def specular_sources(
    tri: Vec, amp: NDArray[Any], kn: Vec, swing: Vec, fine_m: float
) -> tuple[Vec, NDArray[np.complex128]]:
    """Near-specular facets, split to ``fine_m`` pieces, as point sources at the pieces' centroids.

    Each piece's amplitude at a node is its exact closed-form integral there (phases about its centroid),
    times its facet's weight ``amp``; a piece of ``fine_m`` varies by under a radian across the patch, so
    the interpolation between nodes follows it.
    """
    from inference.simulation.kernels import node_integrals

    pieces, parent = bisect(tri, fine_m)
    cen = pieces.mean(axis=1)
    rel = np.ascontiguousarray(pieces - cen[:, None, :])
    block = np.empty((len(pieces), len(kn)), np.complex128)
    nodes = np.asarray(NODES, float)
    node_integrals(rel, kn[len(kn) // 2], swing[0], swing[1], nodes, np.ones(len(pieces)), block)
    return cen, block * amp[parent]


def node_wave_vectors(radar: Radar) -> tuple[Vec, Vec, Vec]:
    """Return the nodes' wave vectors (P, 3; row i * n + j: range node i, cross-range node j), los and the swing.

    ``swing`` (2, 3): the k-patch's half-widths along range and cross-range, as vectors.
    """
    a = projection_matrix(radar)
    los, rate = a[0], a[1]
    k0 = 4.0 * math.pi / radar.wavelength_m
    half_r, half_a = math.pi / radar.range_cell_m, math.pi / radar.cross_range_cell_m
    nodes = np.asarray(NODES, float)
    kn = (k0 + nodes[:, None, None] * half_r) * los + (nodes[None, :, None] * half_a) * rate
    return kn.reshape(-1, 3), los, np.stack([half_r * los, half_a * rate])


def po_echo(
    pm: PreparedMesh,
    rot: Vec,
    imager: Any,
    options: POOptions,
    rng: np.random.Generator,
    scale: tuple[float, float] = (1.0, 1.0),
) -> NDArray[np.complex128]:
    """Return the frame's PO echo on the Cartesian k-grid (as ``Imager.echo`` for point scatterers).

    Every lit facet's exact integral, as sources whose amplitudes are evaluated at ``NODES`` x ``NODES`` wave
    vectors of the frame's k-patch and interpolated across it (one NUFFT per node, the gridding shared): the
    facets' corners and singular edges (``edge_sources``), and near-specular facets split finely
    (``specular_sources``). Obliquity is taken at each node, and the lit set at each cross-range node
    (horizons and shadows that move during the aperture fade across it). An open sheet that the radar's
    line of sight crosses during the aperture is lit on one side, then the other: its obliquity |n . K| is
    imaged as n . K times the sign of n . K on the grid, one extra image per plane (the ``CROSSING_PLANES``
    largest; further ones keep the sign of the aperture's centre). Diffuse (``roughness``) and multi-bounce
    (``bounces``) terms are point sources too. ``scale`` stretches range and cross-range positions in the
    image (the scale-error option).
    """
    radar = imager.radar
    lam = radar.wavelength_m
    kn, los, swing = node_wave_vectors(radar)
    n = len(NODES)
    khat = kn / np.linalg.norm(kn, axis=1, keepdims=True)
    idx, nrm, lit = lit_across(pm, rot, khat[n // 2 * n : n // 2 * n + n])
    obl = nrm @ khat.T
    two_sided = pm.mesh.two_sided[idx]
    obl = np.where(two_sided[:, None], obl, np.maximum(obl, 0.0))
    amp = math.sqrt(4.0 * math.pi) / lam * obl * np.tile(lit, (1, n))
    k0 = kn[len(kn) // 2]
    crossing = two_sided & (np.abs(nrm @ k0) < np.abs(nrm @ swing[0]) + np.abs(nrm @ swing[1]))
    planes, plane_of = _crossing_planes(nrm, crossing)
    pts, cols = _facet_sources(pm, rot, idx[plane_of < 0], amp[plane_of < 0], kn, swing, radar)
    extra_p, extra_a = _extra_sources(pm, rot, idx, nrm, los, lam, options, rng)
    if len(extra_p):  # point-like terms: the same amplitude at every node
        pts = np.concatenate([pts, extra_p])
        cols = np.concatenate([cols, np.repeat(extra_a[:, None], len(kn), axis=1)])
    echo = _image_sources(pts, cols, k0, imager, scale)
    if planes:
        grid = grid_wave_vectors(radar)
        for g, normal in enumerate(planes):
            p, c = _facet_sources(pm, rot, idx[plane_of == g], amp[plane_of == g], kn, swing, radar)
            echo += _image_sources(p, c, k0, imager, scale) * np.sign(grid @ normal)
    return np.asarray(echo * band_factor(radar), np.complex128)


def _crossing_planes(nrm: Vec, crossing: NDArray[np.bool_]) -> tuple[list[Vec], NDArray[np.int64]]:
    """Group the crossing open-sheet facets by plane orientation (normals within ~1e-4): the largest groups."""
    plane_of = np.full(len(nrm), -1, np.int64)
    where = np.flatnonzero(crossing)
    if not len(where):
        return [], plane_of
    keys, inverse, counts = np.unique(np.round(nrm[where] * 1e4), axis=0, return_inverse=True, return_counts=True)
    order = np.argsort(-counts)[:CROSSING_PLANES]
    planes = []
    for g, key in enumerate(order):
        members = where[inverse.ravel() == key]
        plane_of[members] = g
        planes.append(nrm[members].mean(axis=0))
    return planes, plane_of


def grid_wave_vectors(radar: Radar) -> Vec:
    """Return the Cartesian k-grid's wave vectors (N_r, N_a, 3), obs frame."""
    nr, na = radar.n_range, radar.n_azimuth
    a = projection_matrix(radar)
    kc = 4.0 * math.pi * radar.carrier_hz / C_M_S
    kx = kc + 2.0 * math.pi / (nr * radar.range_cell_m) * np.arange(-nr // 2, nr // 2)
    ky = 2.0 * math.pi / (na * radar.cross_range_cell_m) * np.arange(-na // 2, na // 2)
    return np.asarray(kx[:, None, None] * a[0] + ky[None, :, None] * a[1])


def _facet_sources(
    pm: PreparedMesh, rot: Vec, idx: NDArray[np.int64], amp: NDArray[Any], kn: Vec, swing: Vec, radar: Radar
) -> tuple[Vec, NDArray[np.complex128]]:
    """The lit facets ``idx`` (per-node weights ``amp``) as sources: corners and singular edges, or fine pieces."""
    tri = pm.mesh.triangles[idx] @ rot.T
    normal = pm.normals[idx] @ rot.T
    k0 = kn[len(kn) // 2]
    k0t = np.sqrt(np.maximum(k0 @ k0 - (normal @ k0) ** 2, 0.0))
    spec = k0t < KAPPA_SPECULAR * float(np.hypot(*np.linalg.norm(swing, axis=1)))
    rest = np.flatnonzero(~spec)
    used, corner_cols, line_pts, line_cols = edge_sources(
        tri[rest], normal[rest], amp[rest], kn, swing, pm.vertex_id[idx[rest]], pm.unique_vertices @ rot.T
    )
    fine_m = 0.5 * min(radar.range_cell_m, radar.cross_range_cell_m)
    spec_pts, spec_cols = specular_sources(tri[spec], amp[spec], kn, swing, fine_m)
    pts = np.concatenate([pm.unique_vertices[used] @ rot.T, line_pts, spec_pts])
    return pts, np.concatenate([corner_cols, line_cols, spec_cols])


def _image_sources(
    pts: Vec, cols: NDArray[np.complex128], k0: Vec, imager: Any, scale: tuple[float, float]
) -> NDArray[np.complex128]:
    """The echo of sources whose amplitudes are given at the nodes (N, P): NUFFT per node, Lagrange between them."""
    radar = imager.radar
    nr, na = radar.n_range, radar.n_azimuth
    carrier = np.exp(-1j * (pts @ k0))[:, None] * cols
    pts = pts * np.array([scale[0], scale[1], 1.0]) if scale != (1.0, 1.0) else pts
    u, v = imager.pixel_coordinates(pts)
    spectra = nufft_type1(u, v, carrier, nr, na)
    lr = _lagrange(NODES, np.arange(-nr // 2, nr // 2) / (nr / 2))
    la = _lagrange(NODES, np.arange(-na // 2, na // 2) / (na / 2))
    echo = np.zeros((nr, na), np.complex128)
    n = len(NODES)
    for p, (i, j) in enumerate((i, j) for i in range(n) for j in range(n)):
        echo += np.outer(lr[i], la[j]) * spectra[p]
    return echo


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
        p2, a2 = _bounces(pm, rot, idx, nrm, los, lam, options)
        pts.append(p2)
        amps.append(a2)
    return np.concatenate(pts), np.concatenate(amps)


def _bounces(
    pm: PreparedMesh, rot: Vec, idx: NDArray[np.int64], nrm: Vec, los: Vec, lam: float, options: POOptions
) -> tuple[Vec, NDArray[np.complex128]]:
    """The lit facets' ray tubes (``sbr``): launched at most ``tube_m`` wide where they hit the target, followed."""
    facing = np.abs(nrm @ los) > 1e-9  # lit somewhere in the aperture but not at its centre: no tube there
    idx, nrm = idx[facing], nrm[facing]
    start, tnrm, tube = launch_tubes(pm.engine, rot, pm.mesh.triangles[idx] @ rot.T, nrm, los, options.tube_m)
    return bounce_sources(pm.engine, rot, pm.normals, pm.mesh.two_sided, start, tnrm, tube, los, lam, options.bounces)


def rcs_m2(pm: PreparedMesh, rot: Vec, wavelength_m: float, bounces: int = 1, tube_m: float = 0.05) -> float:
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
        options = POOptions(pm.facet_m, bounces, 0.0, tube_m)
        pts, amps = _bounces(pm, rot, idx, nrm, los, wavelength_m, options)
        total += complex(np.sum(amps * np.exp(-1j * (pts @ k_vec))))
    return abs(total) ** 2


def band_factor(radar: Radar) -> Vec:
    """Return |K| / k_c on the Cartesian k-grid (N_r, N_a): the 1 / lambda of the PO amplitude across the patch."""
    k = np.linalg.norm(grid_wave_vectors(radar), axis=-1)
    return np.asarray(k / k[radar.n_range // 2, radar.n_azimuth // 2])


def po_echo_direct(
    pm: PreparedMesh,
    rot: Vec,
    radar: Radar,
    chunk: int = 256,
    samples: tuple[NDArray[np.int64], NDArray[np.int64]] | None = None,
) -> NDArray[np.complex128]:
    """Return the exact PO echo on the Cartesian k-grid (the reference): every lit facet's integral at every sample.

    Each sample K gets sqrt(4 pi) |K| / (4 pi) sum_f |n_f . K/|K|| int_f exp(-j K . x) dS over the facets lit
    along K's own direction (shadows ray-traced once per cross-range column). O(F N_r N_a): seconds for a
    test mesh, minutes for a station. ``samples`` (rows, columns of the grid) evaluates only those, returned
    in their order.
    """
    nr, na = radar.n_range, radar.n_azimuth
    grid = grid_wave_vectors(radar)
    if samples is None:
        rows, cols = (g.ravel() for g in np.meshgrid(np.arange(nr), np.arange(na), indexing="ij"))
    else:
        rows, cols = (np.asarray(g) for g in samples)
    kvec = grid[rows, cols]
    kmag = np.linalg.norm(kvec, axis=1)
    out = np.zeros(len(kvec), np.complex128)
    for col in np.unique(cols):
        at = np.flatnonzero(cols == col)
        direction = grid[nr // 2, col]  # the column's direction at the carrier
        idx, nrm = lit_facets(pm, rot, direction / np.linalg.norm(direction))
        tri = pm.mesh.triangles[idx] @ rot.T
        for s in range(0, len(at), chunk):
            sel = at[s : s + chunk]
            kk, kn = kvec[sel], kmag[sel]
            cos = np.abs(nrm @ (kk / kn[:, None]).T)  # (F, chunk)
            integral = triangle_integral(tri[:, None, :, :], kk[None, :, :])  # (F, chunk)
            out[sel] = np.sqrt(4.0 * np.pi) * kn / (4.0 * np.pi) * (cos * integral).sum(axis=0)
    return out if samples is not None else out.reshape(nr, na)
