"""Render and compare: fit the target's theoretical projection (paper eq. 10) to an enhanced frame.

numpy, scipy and numba only, so the service runs it beside ONNX Runtime without torch.

The renderer. ``inference.simulation.scene.label_mask`` marks every pixel that some surface point
rounds into, then closes the mask with a 3 x 3 cross. ``Renderer.occupancy`` does the
same with two changes that make it smooth in the attitude: a point's count moves to
the neighbouring pixel linearly within 0.1 pixel of the boundary between them (instead
of jumping there), and counts become occupancy by ``1 - exp(-count / 0.35)`` before
the same closing, taken grey; a compiled kernel (numba) does it in one pass over the skin.
The skin is thinned to one point per voxel of 0.9 pixel
(42,000 points for the default target), which is enough to leave no holes. At the
true attitude this reproduces the label to an IoU of 0.99-0.995.

Coarse scale. ``Renderer.coverage`` renders 4x-pooled frames from a skin thinned to
one point per voxel of 3 pixels, each point weighted by the share of a pooled pixel its
skin covers seen from the image plane (at least a line one fine pixel wide where the
skin is edge-on). It is biased by a few tenths of a percent of IoU, enough to prefer an
attitude several degrees from the truth, so it only ever serves to find a start
(``Library``), never to refine one.

The search. ``fit`` refines starts (Swin's answer, its near-mirror, library matches)
at once. Per iteration and hypothesis it renders a 10-point stencil at step h (the
centre, six axis points, three face diagonals), fits the full quadratic through it,
and renders the quadratic's minimum (at most 2 h away); it moves to the best point
seen and shrinks h from 1 deg (at most four iterations) to 0.35 and 0.12 deg (two each). Every render of an
iteration is one batch. The cost is one minus the soft IoU with the enhanced frame,
plus a weak Gaussian prior around Swin's answer (or, for library starts, each one's own), so a hypothesis stays
a refinement of where it began. ``curvature`` then measures the answer's Hessian on a
wider stencil, from which ``inference.trust`` makes the uncertainty.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numba
import numpy as np
from numpy.typing import NDArray

from inference.rotations import (
    euler_from_matrices,
    euler_from_matrix,
    geodesic_deg,
    rotation_matrices,
    so3_exp,
    so3_grid,
    so3_grid_size,
)
from inference.simulation.radar import Radar, projection_matrix
from inference.simulation.targets import TargetModel, surface_normals

Vec = NDArray[np.float64]
F32 = NDArray[np.float32]

FINE_SPACING_PX = 0.9  # skin thinning for the fine renderer, in pixels
COMMON_SPACING_PX = 0.6  # the denser skin of a still pass's common fit (``fit_common``)
COARSE_FACTOR = 4
SHARP_ZONE = 0.1  # half-width (pixels) of the linear hand-over between neighbouring pixels
COUNT_SCALE = 0.35  # counts per pixel at which occupancy reaches 1 - 1/e
STEPS_DEG = (1.0, 0.35, 0.12)
MAX_ITER = (4, 2, 2)  # iterations at each step: the first may have a few degrees to travel
WINDOW_MARGIN_PX = 12


def mirror(angles_deg: Vec) -> Vec:
    """Return the near-mirror attitude (z, -y, -x): the same projection as the body reflected in its own z.

    Reflection M = diag(1, 1, -1) gives M R(z, y, x) M = R(z, -y, -x), and the projection
    along the observation Z ignores the sign of Z, so a body nearly symmetric in z
    looks the same at both attitudes.
    """
    a = np.array(angles_deg, float)
    a[..., 1:] *= -1.0
    return a


def skin_area(points: Vec) -> float:
    """Return the skin's area (m^2) from a uniform sampling: the points times their median spacing squared."""
    from scipy.spatial import cKDTree

    d, _ = cKDTree(points).query(points[:: max(1, len(points) // 5000)], k=2)
    return float(len(points) * np.median(d[:, 1]) ** 2)


def thin(points: Vec, normals: Vec, areas: Vec, spacing_m: float) -> tuple[Vec, Vec, Vec]:
    """Merge the points of each cubic voxel of ``spacing_m``: their centroid, mean normal (sign-free), summed area."""
    cells = np.floor(points / spacing_m).astype(np.int64)
    _, inv = np.unique(cells, axis=0, return_inverse=True)
    inv = inv.ravel()
    n = int(inv.max()) + 1
    count = np.bincount(inv, minlength=n).astype(float)
    centre = np.stack([np.bincount(inv, points[:, i], n) for i in range(3)], axis=1) / count[:, None]
    outer = np.einsum("ni,nj->nij", normals, normals).reshape(-1, 9)
    scatter = np.stack([np.bincount(inv, outer[:, i], n) for i in range(9)], axis=1).reshape(n, 3, 3)
    mean_normal = np.linalg.eigh(scatter)[1][:, :, -1]
    return np.asarray(centre, float), np.asarray(mean_normal, float), np.bincount(inv, areas, n).astype(float)


def pool(frame: NDArray[np.floating], factor: int) -> Vec:
    """Mean-pool a frame [H, W] by ``factor`` (H and W divisible by it)."""
    if factor == 1:
        return np.asarray(frame, float)
    h, w = frame.shape
    return np.asarray(frame, float).reshape(h // factor, factor, w // factor, factor).mean(axis=(1, 3))


@dataclass(frozen=True)
class Window:
    """A crop of the frame: rows r0..r0+h, columns c0..c0+w."""

    r0: int
    c0: int
    h: int
    w: int

    def crop(self, frame: NDArray[Any]) -> NDArray[Any]:
        return frame[self.r0 : self.r0 + self.h, self.c0 : self.c0 + self.w]


@numba.njit(cache=True, nogil=True)
def _occupancy_kernel(m: F32, points: F32, offset: F32, zone: np.float32, rate: np.float32, out: F32) -> None:
    """Fill ``out`` [H, h, w] with the smooth labels: project, splat, ``1 - exp(rate * count)``, close.

    Per hypothesis k, in float32: u = m[k, 0] . p + offset[0] (v likewise); the share of a point
    that goes to the next row is clip((frac(u) - (0.5 - zone)) / (2 zone), 0, 1), the same for
    columns, rows and columns clipped into the window (a share past its last row or column is
    dropped). Then the grey closing with the 3 x 3 cross (dilate with zero outside, erode with one
    outside, keep the original where larger: the closing ``label_mask`` applies, taken grey).

    One compiled pass over the points instead of numpy's dozen (projection, fractions, indices,
    four bincounts): 2.3-4.3 times faster a hypothesis (design/measurements.md, "A compiled
    silhouette renderer"); then a third less again (the counts in float32, the hand-over's division
    a product, no ``exp`` where nothing landed, the closing over padded grids in two passes;
    design/measurements.md, "The renderer's kernel, a third faster"). It lets go of the GIL, so
    ``Checker.check_many``'s threads share the cores. ``tests/inference/test_fit.py`` checks it
    against the same formula written in numpy and scipy.ndimage.
    """
    n_h, h, w = out.shape
    half = np.float32(0.5) - zone
    inv_width = np.float32(1.0) / (np.float32(2.0) * zone)
    one = np.float32(1.0)
    zero = np.float32(0.0)
    o0, o1 = offset[0], offset[1]
    counts = np.zeros((h + 1, w + 1), np.float32)
    # Padded by a pixel on each side: the dilation reads zero outside the window, the erosion one.
    occ = np.zeros((h + 2, w + 2), np.float32)
    grown = np.ones((h + 2, w + 2), np.float32)
    for k in range(n_h):
        counts[:] = 0.0
        a0, a1, a2 = m[k, 0, 0], m[k, 0, 1], m[k, 0, 2]
        b0, b1, b2 = m[k, 1, 0], m[k, 1, 1], m[k, 1, 2]
        for p in range(points.shape[0]):
            x, y, z = points[p, 0], points[p, 1], points[p, 2]
            u = a0 * x + a1 * y + a2 * z + o0
            v = b0 * x + b1 * y + b2 * z + o1
            iu, iv = np.floor(u), np.floor(v)
            fu = min(max((u - iu - half) * inv_width, zero), one)
            fv = min(max((v - iv - half) * inv_width, zero), one)
            r = min(max(int(iu), 0), h - 1)
            c = min(max(int(iv), 0), w - 1)
            gu, gv = one - fu, one - fv
            counts[r, c] += gu * gv
            counts[r + 1, c] += fu * gv
            counts[r, c + 1] += gu * fv
            counts[r + 1, c + 1] += fu * fv
        for i in range(h):
            for j in range(w):
                n = counts[i, j]
                occ[i + 1, j + 1] = zero if n == zero else one - np.exp(n * rate)
        for i in range(1, h + 1):  # dilate with the cross
            for j in range(1, w + 1):
                grown[i, j] = max(max(occ[i, j], occ[i - 1, j]), max(max(occ[i + 1, j], occ[i, j - 1]), occ[i, j + 1]))
        for i in range(1, h + 1):  # erode with the cross, and keep the original where larger
            for j in range(1, w + 1):
                e = min(min(grown[i, j], grown[i - 1, j]), min(min(grown[i + 1, j], grown[i, j - 1]), grown[i, j + 1]))
                out[k, i - 1, j - 1] = max(e, occ[i, j])


def hull_vertices(points: F32) -> F32:
    """The points [N, 3] on their convex hull (all of them where the hull is flat): a linear map's extremes over
    the points lie on them, so a projection's bounding box is theirs (for the default target 1 point in ~100)."""
    from scipy.spatial import ConvexHull, QhullError

    try:
        return np.ascontiguousarray(points[ConvexHull(points).vertices])
    except (QhullError, ValueError):  # fewer than 4 points, or all in a plane
        return points


@dataclass(frozen=True)
class Renderer:
    """A target's silhouette for one radar: fine (``occupancy``) and 4x coarse (``coverage``)."""

    model: TargetModel
    radar: Radar
    spacing_px: float = FINE_SPACING_PX  # the fine skin's thinning
    points: F32 = field(init=False)  # fine skin (N, 3), body frame
    coarse_points: Vec = field(init=False)
    coarse_normals: Vec = field(init=False)
    coarse_areas: Vec = field(init=False)
    outline: F32 = field(init=False)  # the fine skin's convex hull's vertices: their projection spans the skin's
    rows: Vec = field(init=False)  # (2, 3): observation-frame metres to (range, cross-range) pixels
    pixel_m: float = field(init=False)

    def __post_init__(self) -> None:
        r = self.radar
        set_ = object.__setattr__
        set_(self, "rows", projection_matrix(r) / np.array([[r.range_cell_m], [r.cross_range_cell_m]]))
        pixel = math.sqrt(r.range_cell_m * r.cross_range_cell_m)
        set_(self, "pixel_m", pixel)
        surface = np.asarray(self.model.surface, float)
        normals = surface_normals(surface)
        areas = np.full(len(surface), skin_area(surface) / len(surface))
        fine, _, _ = thin(surface, normals, areas, self.spacing_px * pixel)
        set_(self, "points", fine.astype(np.float32))
        set_(self, "outline", hull_vertices(self.points))
        pts, nrm, ar = thin(surface, normals, areas, 0.75 * COARSE_FACTOR * pixel)
        set_(self, "coarse_points", pts)
        set_(self, "coarse_normals", nrm)
        set_(self, "coarse_areas", ar)

    @property
    def shape(self) -> tuple[int, int]:
        return self.radar.n_range, self.radar.n_azimuth

    def pixels(self, angles_deg: Vec, points: NDArray[np.floating] | None = None) -> tuple[F32, F32]:
        """Return fractional pixel rows and columns [H, N] of the skin at attitudes [H, 3]."""
        return self.pixels_of(rotation_matrices(angles_deg), points)

    def pixels_of(self, rotations: Vec, points: NDArray[np.floating] | None = None) -> tuple[F32, F32]:
        """``pixels`` of attitudes given as rotation matrices [H, 3, 3]."""
        pts = self.points if points is None else points
        m = (self.rows[None] @ np.asarray(rotations, float).reshape(-1, 3, 3)).astype(np.float32)  # (H, 2, 3)
        uv = m @ np.asarray(pts, np.float32).T  # (H, 2, N)
        return uv[:, 0] + np.float32(self.radar.n_range / 2), uv[:, 1] + np.float32(self.radar.n_azimuth / 2)

    def occupancy(self, angles_deg: Vec, window: Window | None = None) -> F32:
        """Return the smooth label [H, h, w] of attitudes [H, 3] inside ``window`` (default: the whole frame).

        Points that fall outside the window are counted on its border, so a hypothesis
        never gains by pushing parts of the target out of view.
        """
        return self.occupancy_of(rotation_matrices(angles_deg), window)

    def occupancy_of(self, rotations: Vec, window: Window | None = None) -> F32:
        """``occupancy`` of attitudes given as rotation matrices [H, 3, 3] (body to observation frame)."""
        win = window or Window(0, 0, *self.shape)
        m = (self.rows[None] @ np.asarray(rotations, float).reshape(-1, 3, 3)).astype(np.float32)  # (H, 2, 3)
        offset = np.array([self.radar.n_range / 2 - win.r0, self.radar.n_azimuth / 2 - win.c0], np.float32)
        out = np.empty((len(m), win.h, win.w), np.float32)
        _occupancy_kernel(m, self.points, offset, np.float32(SHARP_ZONE), np.float32(-1.0 / COUNT_SCALE), out)
        return out

    def coverage(self, angles_deg: Vec) -> F32:
        """Return the 4x-pooled silhouette [H, n_range / 4, n_azimuth / 4]: the share of each pixel covered."""
        return self.coverage_of(rotation_matrices(angles_deg))

    def coverage_of(self, rotations: Vec) -> F32:
        """``coverage`` of attitudes given as rotation matrices [H, 3, 3] (``_coverage_kernel``)."""
        f = COARSE_FACTOR
        rot = np.asarray(rotations, float).reshape(-1, 3, 3)
        m = (self.rows[None] @ rot).astype(np.float32)  # (H, 2, 3)
        offset = np.array([self.radar.n_range / 2, self.radar.n_azimuth / 2], np.float32)
        a = self.coarse_areas.astype(np.float32)
        px = np.float32(self.pixel_m)
        out = np.empty((len(rot), self.radar.n_range // f, self.radar.n_azimuth // f), np.float32)
        _coverage_kernel(
            m,
            np.ascontiguousarray(rot[:, 2, :]),
            np.asarray(self.coarse_points, np.float32),
            np.ascontiguousarray(self.coarse_normals, float),
            a,
            np.sqrt(a) * px,
            np.float32((f * px) ** 2),
            offset,
            f,
            out,
        )
        return out


@numba.njit(cache=True, nogil=True)
def _coverage_kernel(
    m: F32,
    depth: Vec,
    points: F32,
    normals: Vec,
    areas: F32,
    edge: F32,
    cell: np.float32,
    offset: F32,
    f: int,
    out: F32,
) -> None:
    """Fill ``out`` [H, n_range / f, n_azimuth / f] with the share of each pooled pixel the coarse skin covers.

    Per hypothesis k and coarse point, in float32: u = (m[k, 0] . p + offset[0] + 0.5) / f - 0.5 (v likewise);
    its weight (area a seen from the image plane, at least an edge-on line sqrt(a) wide: ``edge`` = sqrt(a) x
    pixel) (a |n_z| + edge sqrt(1 - n_z^2)) / ``cell``, with n_z = |depth[k] . normal| (float64, then float32);
    the weight shared bilinearly over the four pooled pixels about (u, v) on a grid padded by one, added in
    float64, then clipped at 1. Indices clip to the padding, and a point past the last padded row or column adds
    at the last pixel's corner (as the numpy formulation it replaced, kept in ``tests/inference/test_fit.py``).
    """
    n_h, nr, na = out.shape
    stride = na + 2
    size = (nr + 2) * stride
    last = size - stride - 2  # the last index whose four cells (i, i + 1, i + stride, i + stride + 1) fit the grid
    grid = np.zeros(size)
    one = np.float32(1.0)
    zero = np.float32(0.0)
    half = np.float32(0.5)
    ff = np.float32(f)
    for k in range(n_h):
        grid[:] = 0.0
        a0, a1, a2 = m[k, 0, 0], m[k, 0, 1], m[k, 0, 2]
        b0, b1, b2 = m[k, 1, 0], m[k, 1, 1], m[k, 1, 2]
        d0, d1, d2 = depth[k, 0], depth[k, 1], depth[k, 2]
        for p in range(points.shape[0]):
            x, y, z = points[p, 0], points[p, 1], points[p, 2]
            u = ((a0 * x + a1 * y + a2 * z) + offset[0] + half) / ff - half
            v = ((b0 * x + b1 * y + b2 * z) + offset[1] + half) / ff - half
            iu, iv = np.floor(u), np.floor(v)
            fu, fv = u - iu, v - iv
            nz = np.float32(abs(d0 * normals[p, 0] + d1 * normals[p, 1] + d2 * normals[p, 2]))
            w = (areas[p] * nz + edge[p] * np.sqrt(max(one - nz * nz, zero))) / cell
            r = int(min(max(iu, -1.0), nr)) + 1
            c = int(min(max(iv, -1.0), na)) + 1
            i = min(r * stride + c, last)
            gu, gv = one - fu, one - fv
            grid[i] += w * gu * gv
            grid[i + stride] += w * fu * gv
            grid[i + 1] += w * gu * fv
            grid[i + stride + 1] += w * fu * fv
        for r in range(nr):
            for c in range(na):
                out[k, r, c] = np.float32(min(grid[(r + 1) * stride + c + 1], 1.0))


def soft_iou(occupancy: F32, target: NDArray[np.floating], target_total: float | None = None) -> Vec:
    """Return the soft IoU of occupancies [H, n, m] with a target [n, m] in [0, 1].

    ``target_total`` is the target's sum over the whole frame when ``target`` is a crop.
    """
    inter, covered = _soft_sums(np.ascontiguousarray(occupancy, np.float32), np.ascontiguousarray(target, np.float32))
    total = float(target.sum()) if target_total is None else target_total
    union = covered + total - inter
    return np.asarray(inter / np.maximum(union, 1e-9))


@numba.njit(cache=True, nogil=True, fastmath={"reassoc", "nsz", "contract"})  # a sum in any order: SIMD
def _soft_sums(occupancy: F32, target: F32) -> tuple[Vec, Vec]:
    """Per hypothesis, the sums (float64) of occupancy x target and of occupancy: one pass, where numpy made two
    and a float64 copy."""
    n_h, h, w = occupancy.shape
    inter = np.zeros(n_h)
    covered = np.zeros(n_h)
    for k in range(n_h):
        a = 0.0
        b = 0.0
        for i in range(h):
            for j in range(w):
                o = occupancy[k, i, j]
                a += o * target[i, j]
                b += o
        inter[k] = a
        covered[k] = b
    return inter, covered


def _stencil() -> Vec:
    e = np.eye(3)
    return np.vstack([np.zeros((1, 3)), e, -e, e[0] + e[1], e[0] + e[2], e[1] + e[2]])


STENCIL = _stencil()  # (10, 3): exactly determines a quadratic in three variables


def _design(d: Vec) -> Vec:
    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    return np.stack([np.ones_like(x), x, y, z, x * x, y * y, z * z, x * y, x * z, y * z], axis=1)


_DESIGN_INV = np.linalg.inv(_design(STENCIL))


def quadratic(values: Vec) -> tuple[Vec, Vec]:
    """Fit c + g.d + d'Hd/2 through the stencil's values (unit step); return the gradient g and Hessian H."""
    c = _DESIGN_INV @ values
    hess = np.array([[2 * c[4], c[7], c[8]], [c[7], 2 * c[5], c[9]], [c[8], c[9], 2 * c[6]]])
    return c[1:4], hess


def quadratic_step(values: Vec) -> Vec | None:
    """The stencil quadratic's minimum (unit step, clipped to 2 a axis), or None where it curves down or is singular."""
    g, hess = quadratic(values)
    if not np.all(np.linalg.eigvalsh(hess) > 1e-12):
        return None
    d = -np.linalg.solve(hess, g)
    return np.clip(d, -2.0, 2.0) if np.all(np.isfinite(d)) else None


@dataclass(frozen=True)
class Fit:
    """One refined hypothesis: attitude (deg), soft IoU, cost (with the prior), and the start it began from."""

    angles_deg: Vec
    iou: float
    cost: float
    start: str


@dataclass(frozen=True)
class FitOptions:
    """The search's knobs (defaults measured in BENCHMARKS.md)."""

    steps_deg: tuple[float, ...] = STEPS_DEG
    max_iter: tuple[int, ...] = MAX_ITER  # per step; the last entry serves any further steps
    prior_sigma_deg: float = 10.0
    prior_weight: float = 0.002  # cost at one sigma from the start: 0.2 % of IoU
    prune: float = 0.03  # drop a hypothesis whose cost is this far behind the best after the first step
    # Prune on the starts' own costs too, before any has moved (off: only after the first step's iterations). A
    # library entry lies up to about half a spacing from its basin, and its cost there says little about the basin's:
    # an entry 13 deg from the truth started 0.06 behind the best and ended the coarse fit 0.09 ahead of it
    # (design/measurements.md, "Neighbouring basins and the library's starts").
    prune_at_start: bool = True
    coarse: bool = False  # fit the 4x-pooled coverage instead (Renderer.coverage): smooth but biased, for far starts
    # Step in a rotation vector about each start (deg, observation-frame axes) instead of in the Euler angles:
    # the same step turns the body the same whatever the attitude, where near y = +-90 deg two Euler angles turn it
    # about one axis and the third direction is lost (gimbal lock). The library's fits, whose starts lie anywhere.
    local: bool = False


def fit(
    renderer: Renderer,
    enhanced: Vec,
    starts: dict[str, Vec],
    options: FitOptions | None = None,
    prior_at: Vec | None = None,
    keep: tuple[str, ...] = (),
) -> list[Fit]:
    """Refine each start (name -> (z, y, x) deg) against the enhanced frame; return the fits, best first.

    The prior pulls each hypothesis toward its own start, or toward ``prior_at`` for all of
    them (what the network saw: its near-mirror then has to fit clearly better to win).
    The starts named in ``keep`` are refined whatever their first cost: with the prior at Swin's answer, its
    near-mirror (z, -y, -x) starts 0.00008 (y^2 + x^2) behind on the prior alone, so pruning dropped it
    beyond sqrt(y^2 + x^2) = 19 deg before it was refined, whatever its silhouette's fit.
    """
    opt = options or FitOptions()
    if opt.local and prior_at is not None:
        raise ValueError("a local fit's prior sits on each start (its rotation vector's origin): no prior_at")
    target = np.clip(np.asarray(enhanced, np.float32), 0.0, 1.0)
    total = float(target.sum(dtype=np.float64))
    names = list(starts)
    origin = np.array([starts[n] for n in names], float).reshape(-1, 3)
    base = rotation_matrices(origin)  # each start's rotation: a local fit's offsets turn it
    best = np.zeros_like(origin) if opt.local else origin.copy()
    centre = best.copy() if prior_at is None else np.broadcast_to(np.asarray(prior_at, float), origin.shape)

    def rotations(points: Vec, live: NDArray[np.intp]) -> Vec:
        """The rotations [L, S, 3, 3] of points [L, S, 3] of the hypotheses ``live``."""
        if not opt.local:
            return rotation_matrices(points.reshape(-1, 3)).reshape(*points.shape[:-1], 3, 3)
        return np.einsum("lsij,ljk->lsik", so3_exp(np.radians(points)), base[live])

    def angles_of(points: Vec, live: NDArray[np.intp]) -> Vec:
        return points if not opt.local else euler_from_matrices(rotations(points[:, None], live)).reshape(-1, 3)

    best_cost = np.full(len(names), np.inf)
    best_iou = np.zeros(len(names))
    alive = np.ones(len(names), bool)
    kept = np.array([n in keep for n in names], bool)
    silhouette = target > 0.5
    pooled = pool(target, COARSE_FACTOR) if opt.coarse else target

    def cost(points: Vec, live: NDArray[np.intp]) -> tuple[Vec, Vec]:
        rot = rotations(points, live).reshape(-1, 3, 3)
        if opt.coarse:
            iou = soft_iou(renderer.coverage_of(rot), pooled).reshape(points.shape[:-1])
        else:
            # The window: the frame's silhouette and where the centres put the target, with a margin.
            win = _window_for(renderer, silhouette, angles_of(best[live], live))
            iou = soft_iou(renderer.occupancy_of(rot, win), win.crop(target), total).reshape(points.shape[:-1])
        prior = opt.prior_weight * np.sum(((points - centre[live][:, None, :]) / opt.prior_sigma_deg) ** 2, axis=-1)
        return 1.0 - iou + prior, iou

    # Score every start first, and refine only those that begin within ``prune`` of the best.
    c0, iou0 = cost(best[:, None, :], np.arange(len(names)))
    best_cost, best_iou = c0[:, 0].copy(), iou0[:, 0].copy()
    if opt.prune > 0 and opt.prune_at_start:
        alive &= (best_cost <= best_cost.min() + opt.prune) | kept
    for step_no, h in enumerate(opt.steps_deg):
        for _ in range(opt.max_iter[min(step_no, len(opt.max_iter) - 1)]):
            live = np.flatnonzero(alive)
            pts = best[live][:, None, :] + h * STENCIL[None]
            c, iou = cost(pts, live)
            moved = np.zeros(len(live), bool)
            proposals = np.empty((len(live), 3))
            for j, k in enumerate(live):
                if c[j, 0] < best_cost[k]:
                    best_cost[k], best_iou[k] = c[j, 0], iou[j, 0]
                d = quadratic_step(c[j])
                i = int(np.argmin(c[j]))
                proposals[j] = best[k] + h * (STENCIL[i] if d is None else d)
                if c[j, i] < best_cost[k]:  # a stencil point beat the centre: go there at least
                    moved[j] = True
                    best[k] = best[k] + h * STENCIL[i]
                    best_cost[k], best_iou[k] = c[j, i], iou[j, i]
            c2, iou2 = cost(proposals[:, None, :], live)
            better = c2[:, 0] < best_cost[live]
            best[live[better]] = proposals[better]
            best_cost[live[better]], best_iou[live[better]] = c2[better, 0], iou2[better, 0]
            if step_no == 0 and opt.prune > 0:
                alive &= (best_cost <= best_cost.min() + opt.prune) | kept
            if not np.any(moved | better):
                break
    order = np.argsort(np.where(alive, best_cost, np.inf))
    answers = angles_of(best, np.arange(len(names)))
    return [Fit(answers[k].copy(), float(best_iou[k]), float(best_cost[k]), names[k]) for k in order if alive[k]]


COMMON_STEPS_DEG = (0.35, 0.12, 0.05)
COMMON_MAX_ITER = (4, 3, 3)


@dataclass(frozen=True)
class CommonFit:
    """A still pass's attitude fitted to all its frames at once: body to LVLH, the move from the start, the mean IoU."""

    rotation: Vec
    moved_deg: float
    iou: float
    frames: int


def fit_common(renderer: Renderer, enhanced: list[Vec], observation_in_lvlh: list[Vec], rotation: Vec) -> CommonFit:
    """Refine one attitude (body to LVLH, ``rotation``) against every frame's enhanced silhouette at once.

    Frame k sees the body at ``observation_in_lvlh[k].T @ R``; the cost is the frames' mean of
    1 - soft IoU, searched as ``fit`` searches one frame (the 10-point stencil and its quadratic)
    over small turns of the body, R exp(d) with d in Euler z, y, x about the body, at steps of
    0.35, 0.12 and 0.05 deg. A still pass's frames see one attitude from several sides: where
    each frame's own fit is pulled off by its silhouette's edge pixels, the sum of their costs
    is a smoother surface than any one of them, and its minimum is the attitude they share
    (design/measurements.md, "A still pass fitted to all its frames at once").
    """
    targets = [np.clip(np.asarray(e, np.float32), 0.0, 1.0) for e in enhanced]
    silhouettes = [t > 0.5 for t in targets]
    totals = [float(t.sum(dtype=np.float64)) for t in targets]
    obs = [np.asarray(o, float) for o in observation_in_lvlh]
    start = np.asarray(rotation, float)

    def cost(deltas: Vec) -> tuple[Vec, Vec]:
        rots = start[None] @ rotation_matrices(deltas)  # body to LVLH
        iou = np.zeros(len(deltas))
        for o, target, sil, total in zip(obs, targets, silhouettes, totals, strict=True):
            seen = o.T[None] @ rots  # body to this frame's observation axes
            win = _window_for(renderer, sil, np.array([euler_from_matrix(seen[0])]))
            iou += soft_iou(renderer.occupancy_of(seen, win), win.crop(target), total)
        iou /= len(obs)
        return 1.0 - iou, iou

    best = np.zeros(3)
    c0, i0 = cost(best[None])
    best_cost, best_iou = float(c0[0]), float(i0[0])
    for h, n_iter in zip(COMMON_STEPS_DEG, COMMON_MAX_ITER, strict=True):
        for _ in range(n_iter):
            c, iou = cost(best + h * STENCIL)
            moved = False
            d = quadratic_step(c)
            if d is not None:
                cp, ip = cost((best + h * d)[None])
                if cp[0] < min(best_cost, float(c.min())):
                    best, best_cost, best_iou, moved = best + h * d, float(cp[0]), float(ip[0]), True
            i = int(np.argmin(c))
            if not moved and c[i] < best_cost:
                best, best_cost, best_iou, moved = best + h * STENCIL[i], float(c[i]), float(iou[i]), True
            if not moved:
                break
    final = start @ rotation_matrices(best[None])[0]
    moved_deg = float(geodesic_deg(np.zeros(3), best)[0])
    return CommonFit(final, moved_deg, best_iou, len(obs))


CURVATURE_STEP_DEG = 0.6  # the stencil that measures the answer's curvature: wide enough to see past pixel steps


def _window_for(renderer: Renderer, silhouette: NDArray[np.bool_], angles_deg: Vec) -> Window:
    """The crop holding the frame's silhouette and the target at these attitudes, with a margin."""
    u, v = renderer.pixels(np.asarray(angles_deg, float).reshape(-1, 3), renderer.outline)  # the skin's extremes
    rows, cols = np.flatnonzero(silhouette.any(axis=1)), np.flatnonzero(silhouette.any(axis=0))
    r_lo = min(float(u.min()), float(rows[0]) if len(rows) else math.inf)
    r_hi = max(float(u.max()), float(rows[-1]) if len(rows) else -math.inf)
    c_lo = min(float(v.min()), float(cols[0]) if len(cols) else math.inf)
    c_hi = max(float(v.max()), float(cols[-1]) if len(cols) else -math.inf)
    n_r, n_c = silhouette.shape
    r0, r1 = max(int(r_lo) - WINDOW_MARGIN_PX, 0), min(int(r_hi) + WINDOW_MARGIN_PX + 1, n_r)
    c0, c1 = max(int(c_lo) - WINDOW_MARGIN_PX, 0), min(int(c_hi) + WINDOW_MARGIN_PX + 1, n_c)
    if r1 <= r0 or c1 <= c0:
        return Window(0, 0, n_r, n_c)
    return Window(r0, c0, r1 - r0, c1 - c0)


def _hard_ious(occupancy: F32, win: Window, silhouette: NDArray[np.bool_]) -> Vec:
    """Hard IoU of labels (occupancy > 0.5, inside ``win``) with the whole frame's silhouette."""
    label = occupancy > 0.5
    inter = np.count_nonzero(label & win.crop(silhouette), axis=(1, 2))
    union = np.count_nonzero(label, axis=(1, 2)) + int(silhouette.sum()) - inter
    return np.asarray(inter / np.maximum(union, 1), float)


def silhouette_iou(renderer: Renderer, angles_deg: Vec, enhanced: Vec) -> Vec:
    """Return the hard IoU of each attitude's label (occupancy > 0.5) with the enhanced silhouette (> 0.5)."""
    sil = np.asarray(enhanced) > 0.5
    angles = np.asarray(angles_deg, float).reshape(-1, 3)
    win = _window_for(renderer, sil, angles)
    return _hard_ious(renderer.occupancy(angles, win), win, sil)


def curvature(
    renderer: Renderer, enhanced: Vec, angles_deg: Vec, step_deg: float = CURVATURE_STEP_DEG
) -> tuple[Vec, float, float]:
    """Return the Hessian (per deg^2) of 1 - soft IoU at an attitude, the soft IoU and the hard IoU there.

    The Hessian is the quadratic's through the 10-point stencil at ``step_deg``; the hard
    IoU is the stencil centre's label (occupancy > 0.5) against the silhouette (> 0.5).
    """
    target = np.clip(np.asarray(enhanced, np.float32), 0.0, 1.0)
    sil = target > 0.5
    pts = np.asarray(angles_deg, float) + step_deg * STENCIL
    win = _window_for(renderer, sil, pts)
    occ = renderer.occupancy(pts, win)
    iou = soft_iou(occ, win.crop(target), float(target.sum(dtype=np.float64)))
    _, hess = quadratic(1.0 - iou)
    return hess / step_deg**2, float(iou[0]), float(_hard_ious(occ[:1], win, sil)[0])


BRIGHTNESS_BLUR_PX = 1.5


def brightness_agreement(renderer: Renderer, frame: Vec, angles_deg: Vec, mask: NDArray[np.bool_]) -> float:
    """Return how well an attitude explains which parts of the frame are bright: a correlation in [-1, 1].

    What the silhouette cannot show: the scatterers the radar sees at that attitude (facing
    it, not hidden behind nearer parts: ``inference.simulation.scene.visible``), each with its expected
    aspect-dependent power (``expected_magnitude``), splatted and blurred by 1.5 pixels, in
    log scale, against the normalised frame (itself in dB) blurred alike, over ``mask``. The
    near-mirror's silhouette can match within a tenth of a percent while its bright parts
    (which wing flashes, which side of a module faces the radar) do not.
    """
    from scipy.ndimage import gaussian_filter

    from inference.simulation.scene import expected_magnitude, visible

    model, radar = renderer.model, renderer.radar
    rot = rotation_matrices(np.asarray(angles_deg, float))[0]
    pts, normals = model.scatterers @ rot.T, model.normals @ rot.T
    los = projection_matrix(radar)[0]
    seen = visible(pts, normals, model.kinds, los)
    power = expected_magnitude(normals[seen], model.kinds[seen], los) ** 2
    uv = pts[seen] @ renderer.rows.T  # the pixel mapping of the label and the simulator
    iu = np.clip(np.rint(uv[:, 0] + radar.n_range / 2).astype(np.int64), 0, radar.n_range - 1)
    iv = np.clip(np.rint(uv[:, 1] + radar.n_azimuth / 2).astype(np.int64), 0, radar.n_azimuth - 1)
    image = np.bincount(iu * radar.n_azimuth + iv, power, radar.n_range * radar.n_azimuth).reshape(
        radar.n_range, radar.n_azimuth
    )
    image = gaussian_filter(image, BRIGHTNESS_BLUR_PX)
    x = np.log(image[mask] + 1e-3 * max(float(image.max()), 1e-12))
    y = gaussian_filter(np.asarray(frame, float), BRIGHTNESS_BLUR_PX)[mask]
    if len(x) < 10 or np.std(x) == 0 or np.std(y) == 0:
        return 0.0
    return float(np.corrcoef(x, y)[0, 1])


LIBRARY_SPACING_DEG = 15.0  # measured: design/measurements.md, "The coarse silhouette library over SO(3)"
LIBRARY_MAX_SPACING_DEG = 20.0  # beyond it the nearest entry can lie outside the coarse fit's reach


class LibraryError(ValueError):
    """A library the coarse renderer cannot use: its spacing, named, with what would do."""

    field = "library_spacing_deg"


def library_spacing_limits(renderer: Renderer) -> tuple[float, float]:
    """The spacings (deg) a library of ``renderer``'s target can have: at least the turn that moves the target's
    farthest point by one coarse pixel (closer entries cannot be told apart at the coarse resolution), at most
    ``LIBRARY_MAX_SPACING_DEG``."""
    radius_px = float(np.max(np.linalg.norm(renderer.coarse_points, axis=1))) / renderer.pixel_m
    return math.degrees(COARSE_FACTOR / max(radius_px, 1e-9)), LIBRARY_MAX_SPACING_DEG


@dataclass(frozen=True)
class Library:
    """Coarse silhouettes of attitudes spread evenly over all of SO(3) (``so3_grid``): the starts of the search
    where no network answer fits (a target without networks, an attitude outside their cube).

    Built once per target (4,400 attitudes at 15 deg, about 0.6 s and 44 MB;
    design/measurements.md, "The coarse silhouette library over SO(3)"); ``starts`` scores every entry against a
    frame's 4x-pooled enhanced silhouette in one product and returns the best few, each at least ``separation_deg``
    from the others. The silhouettes keep only the pooled pixels some entry covers (``columns``: 2,514 of 4,096 for
    the default target), in float32, so the product is one BLAS call of about a millisecond where converting float16
    took 49 (design/measurements.md, "The renderer's kernel, a third faster").
    """

    angles_deg: Vec
    silhouettes: NDArray[np.float32]  # (M, len(columns))
    totals: Vec
    columns: NDArray[np.intp]  # the pooled pixels (flat, n / 4 * n / 4) that some entry covers

    @staticmethod
    def build(renderer: Renderer, spacing_deg: float | None = None, batch: int = 128) -> Library:
        """The library at ``spacing_deg``, or by default ``LIBRARY_SPACING_DEG`` moved into the limits the target
        allows (a target a few coarse pixels across resolves nothing finer than the widest spacing: that one)."""
        lo, hi = library_spacing_limits(renderer)
        if spacing_deg is None:
            spacing_deg = min(max(LIBRARY_SPACING_DEG, lo), hi)
        elif not (math.isfinite(spacing_deg) and lo <= spacing_deg <= hi):
            raise LibraryError(
                f"library spacing {spacing_deg:g} deg: this target and radar resolve {lo:.1f} to {hi:g} deg (closer "
                "entries look alike at the coarse resolution; farther ones leave attitudes out of the fit's reach)"
            )
        angles = euler_from_matrices(so3_grid(so3_grid_size(spacing_deg)))
        parts = [
            renderer.coverage(angles[k : k + batch]).reshape(
                -1, (renderer.shape[0] // COARSE_FACTOR) * (renderer.shape[1] // COARSE_FACTOR)
            )
            for k in range(0, len(angles), batch)
        ]
        sil = np.concatenate(parts)
        columns = np.flatnonzero(sil.max(axis=0) > 0)
        return Library(angles, np.ascontiguousarray(sil[:, columns]), sil.sum(axis=1, dtype=np.float64), columns)

    def starts(self, enhanced: Vec, count: int = 4, separation_deg: float = 15.0) -> list[Vec]:
        """Return up to ``count`` library attitudes that best match the enhanced frame, best first."""
        target = pool(np.clip(np.asarray(enhanced, float), 0.0, 1.0), COARSE_FACTOR).ravel()
        inter = self.silhouettes @ target[self.columns].astype(np.float32)  # no entry covers the other pixels
        iou = inter / np.maximum(self.totals + target.sum() - inter, 1e-9)
        chosen: list[Vec] = []
        for k in np.argsort(-iou):
            a = self.angles_deg[k]
            if all(geodesic_deg(a, c)[0] >= separation_deg for c in chosen):
                chosen.append(a.copy())
                if len(chosen) == count:
                    break
        return chosen
