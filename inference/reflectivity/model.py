"""The reflectivity map: what one radar sees of the target, as the mean intensity of its image at any attitude.

numpy, scipy and numba only (the service's side). Under fully developed speckle the intensity of a pixel is
exponential about its mean, and the mean is the incoherent sum of what every part of the skin returns, each through
the radar's point spread. So the map predicts a frame's mean intensity

    mu(pixel) = g * sum_s vis_s * I_s * |h_r(u - u_s)|^2 |h_a(v - v_s)|^2 + b

over sites s sampled on the target's skin (``inference.reflectivity.sites``), at their pixels (u_s, v_s) in the image
plane; ``vis_s`` is the depth buffer's soft visibility across the line of sight, ``b`` the frame's noise floor and
``g`` its gain (normalised frames lose the absolute scale). A site returns

    I_s = a_s L_part(theta_s) + rho_part * spec_s

* ``a_s L_part(theta_s)``: the diffuse return: the site's area times its part's aspect law, piecewise linear in the
  angle between the site's normal and the line of sight over ``LAW_NODES_DEG`` (two-sided sites take the nearer side;
  closed skin facing away returns nothing). A part is a connected piece of the mesh (a module, a wing): one law each.
  A weight per site, tried first, fitted the labelled frames better and held-out frames worse, and moved refined
  attitudes further from the truth (design/measurements.md, "The reflectivity map's parameters");
* ``rho_part * spec_s``: the specular flash from physical optics: the site's share of its flat panel's lobe,
  ``4 pi a_s A / lambda^2`` times a Gaussian in the line of sight's tilt off the panel's normal along each of its
  in-plane axes, of width 0.188 lambda / extent (the sinc^2 lobe's half-power width) widened by the aperture's swing
  along that axis (the frame averages the lobe over the swing). ``rho`` is learnt per part, so a flash at an
  attitude no labelled frame showed comes from geometry, not from memory.

The point spread is the radar's window (``Look.window``), optionally blurred (``Look.blur_px``); ``Look.scale``
scales the cells and ``Look.occlusion`` switches the depth buffer: the choices ``inference.reflectivity.build``
selects by leaving labelled scenes out.

A frame's pixels are read back to intensity relative to its 99.5th percentile (``inference.frames.normalise_frame``
inverted): 0 is "at or below -40 dB" and 1 "at or above the reference", both censored, so the likelihood takes each
as the probability of its side (``nll``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from inference.reflectivity import kernels
from inference.reflectivity.sites import Sites
from inference.simulation.radar import Radar, line_of_sight, window_1d

Vec = NDArray[np.float64]
F32 = NDArray[np.float32]

# The aspect law's nodes, in degrees between the normal and the line of sight: dense near 0, where specular lobes of a
# few degrees live (nodes even in the cosine would put all of 0-31 deg between two nodes).
LAW_NODES_DEG = (0.0, 1.0, 2.0, 3.0, 5.0, 8.0, 12.0, 20.0, 35.0, 60.0, 90.0)
LAW_BINS = len(LAW_NODES_DEG)
OVERSAMPLE = 16  # point-spread table samples per pixel
PSF_FLOOR = 1e-3  # the point spread is cut where |h|^2 stays under this (-30 dB) on each axis
PSF_MAX_HALF_PX = 5.0
TAPER_PX = 0.5
LOBE_WIDTH = 0.188  # sigma of the Gaussian with the sinc^2 lobe's half-power width, in lambda / extent
DYNAMIC_RANGE_DB = 40.0  # normalise_frame's
OCCLUSION_CELL_M = 0.25
OCCLUSION_TOL_M = 0.25
BACKGROUND_QUANTILE = 0.3  # the frame's floor from this quantile of its pixels (exponential: q = -b ln(1 - p))
WINDOWS = ("taylor", "hamming", "none")
_NODES = np.array(LAW_NODES_DEG)
_SPANS = np.diff(_NODES)


@dataclass(frozen=True)
class Look:
    """How the radar images, as the map models it: its window, an extra blur, the cell scale, occlusion."""

    window: str = "taylor"
    blur_px: float = 0.0
    scale: float = 1.0
    occlusion: bool = True

    def __post_init__(self) -> None:
        if self.window not in WINDOWS:
            raise ValueError(f"window {self.window!r} is not one of {', '.join(WINDOWS)}")
        if not 0.0 <= self.blur_px <= 5.0 or not 0.8 <= self.scale <= 1.25:
            raise ValueError(f"blur_px {self.blur_px} or scale {self.scale} out of range (0-5 px, 0.8-1.25)")


def psf_table(n: int, window: str, sidelobe_db: float, blur_px: float) -> tuple[F32, float]:
    """|h(delta)|^2 of one axis (peak 1 without blur) sampled every 1/OVERSAMPLE pixel over +-half; returns (table, half).

    h is the windowed inverse DFT the imaging applies, ``sum_m w_m exp(2 pi j m delta / n) / sum_m w_m``; a blur is a
    Gaussian of ``blur_px`` convolved with it (in intensity)."""
    w = window_1d(n, window, sidelobe_db)
    m = np.arange(-n // 2, n // 2)
    reach = 12.0 + 4.0 * blur_px
    d = np.arange(-reach, reach + 1e-9, 1.0 / OVERSAMPLE)
    h2 = np.abs(np.exp(2j * np.pi * np.outer(d, m) / n) @ w) ** 2 / float(w.sum()) ** 2
    if blur_px > 0:
        from scipy.ndimage import gaussian_filter1d

        h2 = gaussian_filter1d(h2, blur_px * OVERSAMPLE, mode="constant")
    above = np.abs(d[h2 > PSF_FLOOR * h2.max()])
    reach = float(np.ceil(above.max() * OVERSAMPLE) / OVERSAMPLE) + TAPER_PX
    half = min(reach, PSF_MAX_HALF_PX + blur_px * 2)
    keep = np.abs(d) <= half + 1e-9
    # Tapered to 0 over the last TAPER_PX (beyond the -30 dB reach), so a site's spread has no step where a pixel
    # enters or leaves it.
    taper = np.clip((half - np.abs(d[keep])) / TAPER_PX, 0.0, 1.0)
    return np.ascontiguousarray(h2[keep] * np.sin(0.5 * np.pi * taper) ** 2, np.float32), half


def frame_intensity(frame: NDArray[np.floating]) -> tuple[Vec, NDArray[np.bool_], NDArray[np.bool_]]:
    """A normalised frame [H, W] read back to intensity relative to its reference; and which pixels are censored
    below (at 0: -40 dB or less) and above (at 1: the reference or more)."""
    v = np.asarray(frame, np.float64)
    y = 10.0 ** ((v - 1.0) * DYNAMIC_RANGE_DB / 10.0)
    return y, v <= 1e-6, v >= 0.999


def floor_of(y: Vec) -> float:
    """The frame's noise floor (mean intensity of a pixel with no target), from its BACKGROUND_QUANTILE."""
    q = float(np.quantile(y, BACKGROUND_QUANTILE))
    return max(q / -math.log(1.0 - BACKGROUND_QUANTILE), 10.0 ** (-DYNAMIC_RANGE_DB / 10.0) / 4)


LOW = 10.0 ** (-DYNAMIC_RANGE_DB / 10.0)  # the intensity under which a pixel reads 0


def nll(mu: Vec, y: Vec, low: NDArray[np.bool_], high: NDArray[np.bool_], shape: float | None = None) -> float:
    """The negative log-likelihood of the frame's pixels about the mean ``mu``, summed (constants dropped).

    ``shape`` None: fully developed speckle, exponential: y/mu + log mu where seen, -log P(below LOW), -log P(above
    1) where censored. ``shape`` alpha > 1: speckle on a texture whose inverse is Gamma-distributed (the single-look
    G0 law of SAR clutter, Frery et al. 1997), which is Lomax: p(y) = alpha beta^alpha / (y + beta)^(alpha + 1) with
    beta = mu (alpha - 1): heavier-tailed, so a bright point the map cannot place costs less than a pull on the
    attitude. It tends to the exponential as alpha grows."""
    seen = ~(low | high)
    if shape is None:
        out = float(np.sum(y[seen] / mu[seen] + np.log(mu[seen])))
        if low.any():
            out -= float(np.sum(np.log(-np.expm1(-LOW / mu[low]))))
        if high.any():
            out += float(np.sum(1.0 / mu[high]))
        return out
    a = float(shape)
    beta = mu * (a - 1.0)
    out = float(np.sum((a + 1.0) * np.log(y[seen] + beta[seen]) - a * np.log(beta[seen])))
    if low.any():  # P(y <= LOW) = 1 - (beta / (LOW + beta))^alpha
        b = beta[low]
        out -= float(np.sum(np.log(-np.expm1(a * np.log(b / (LOW + b))))))
    if high.any():  # P(y >= 1) = (beta / (1 + beta))^alpha
        b = beta[high]
        out -= float(np.sum(a * np.log(b / (1.0 + b))))
    return out


def imputed(mu: Vec, y: Vec, low: NDArray[np.bool_], high: NDArray[np.bool_]) -> Vec:
    """The intensity with each censored pixel replaced by its expectation given its side (the EM step)."""
    out = y.copy()
    if low.any():
        m = mu[low]
        e = np.exp(-LOW / m)
        out[low] = m - LOW * e / np.maximum(1.0 - e, 1e-300)
    if high.any():
        out[high] = 1.0 + mu[high]  # memoryless
    return out


@dataclass(frozen=True)
class Geometry:
    """Where the sites fall and how they face at one attitude: pixels ``u``, ``v``; cosine ``c`` (|c| where two-sided;
    negative: facing away); ``vis``; ``spec`` (the specular term before rho)."""

    u: Vec
    v: Vec
    c: Vec
    vis: Vec
    spec: Vec


@dataclass
class ReflectivityMap:
    """A map for one target and radar: its sites, the look, and the learnt laws and reflectivities per part."""

    sites: Sites
    radar: Radar
    look: Look = field(default_factory=Look)
    law: Vec | None = None  # (parts x LAW_BINS) flattened; None: ones
    rho: Vec | None = None  # per part; None: zeros (no specular term)
    record: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.law is None:
            self.law = np.ones(self.sites.n_parts * LAW_BINS)
        if self.rho is None:
            self.rho = np.zeros(self.sites.n_parts)
        r = self.radar
        self._table_r, self._half_r = psf_table(r.n_range, self.look.window, r.window_sidelobe_db, self.look.blur_px)
        self._table_a, self._half_a = psf_table(r.n_azimuth, self.look.window, r.window_sidelobe_db, self.look.blur_px)
        los, d = line_of_sight(math.radians(r.pitch_deg), 0.0)
        self._los = np.asarray(los, float)
        self._across = np.asarray(d, float)
        self._height = np.cross(self._los, self._across)
        self._cells = np.array([r.range_cell_m, r.cross_range_cell_m]) * self.look.scale
        self._centre = np.array([r.n_range / 2, r.n_azimuth / 2], float)
        s = self.sites
        self._spec_peak = 4.0 * math.pi * s.areas * s.panel_area_m2[s.panel] / r.wavelength_m**2
        self._sigma0 = LOBE_WIDTH * r.wavelength_m / s.panel_extent_m  # (P, 2)

    def geometry(self, rotation: Vec) -> Geometry:
        """The sites' pixels, cosines, visibility and specular terms at one attitude (rotation body -> observation)."""
        s, r = self.sites, self.radar
        rot = np.ascontiguousarray(rotation, float)
        n = len(s)
        u, v, c, depth = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
        plane = np.empty((n, 2))
        kernels.site_geometry(
            rot, s.points, s.normals, s.two_sided, self._los, self._across, self._height, self._cells,
            self._centre, u, v, c, depth, plane,
        )  # fmt: skip
        los_b = rot.T @ self._los  # the line of sight and the aperture's swing direction in the body frame
        swing_b = rot.T @ self._across
        front = c > 0.0
        vis = np.ones(n)
        if self.look.occlusion:
            kernels.soft_visibility(depth, plane, front, OCCLUSION_CELL_M, OCCLUSION_TOL_M, vis)
        else:
            vis = front.astype(float)
        # Specular: the line of sight's tilt off each panel's normal along its in-plane axes, and the swing's.
        tilt = s.panel_axes @ los_b  # (P, 2)
        sweep = math.radians(r.aperture_deg) * (s.panel_axes @ swing_b)
        sigma2 = self._sigma0**2 + sweep**2 / 12.0
        facing = s.panel_normal @ los_b
        lobe = np.prod(self._sigma0 / np.sqrt(sigma2), axis=1) * np.exp(-0.5 * np.sum(tilt**2 / sigma2, axis=1))
        spec = self._spec_peak * lobe[s.panel] * (np.where(s.two_sided, np.abs(facing[s.panel]), facing[s.panel]) > 0)
        return Geometry(u, v, c, vis, spec)

    def law_weights(self, c: Vec, part: NDArray[np.intp]) -> tuple[NDArray[np.intp], Vec]:
        """The law nodes (flat index: part x LAW_BINS + node) each site's angle falls between, the upper one's
        share (piecewise linear in the angle)."""
        angle = np.degrees(np.arccos(np.clip(c, 0.0, 1.0)))
        node = np.clip(np.searchsorted(_NODES, angle, side="right") - 1, 0, LAW_BINS - 2)
        frac = (angle - _NODES[node]) / _SPANS[node]
        return part * LAW_BINS + node, frac

    def law_at(self, c: Vec, part: NDArray[np.intp]) -> Vec:
        assert self.law is not None
        lo, f = self.law_weights(c, part)
        return self.law[lo] * (1.0 - f) + self.law[lo + 1] * f

    def intensity(self, g: Geometry) -> Vec:
        """Each site's return I_s times its visibility (0 where facing away)."""
        assert self.rho is not None
        out = (self.sites.areas * self.law_at(g.c, self.sites.part) + self.rho[self.sites.part] * g.spec) * g.vis
        return np.where(g.c > 0.0, out, 0.0)

    def splat(self, g: Geometry, values: Vec, window: tuple[int, int, int, int]) -> Vec:
        """Sum ``values`` through the point spread into the frame's ``window`` (r0, c0, h, w)."""
        r0, c0, h, w = window
        out = np.zeros((h, w))
        live = values > 0
        kernels.splat(
            g.u[live], g.v[live], values[live], self._table_r, self._table_a, self._half_r, self._half_a,
            float(OVERSAMPLE), float(r0), float(c0), out,
        )  # fmt: skip
        return out

    def gather(self, g: Geometry, q1: Vec, q2: Vec, window: tuple[int, int, int, int]) -> tuple[Vec, Vec]:
        """The adjoint of ``splat``: per site, its point spread summed against ``q1`` and ``q2`` (window-sized)."""
        r0, c0, _, _ = window
        o1 = np.zeros(len(g.u))
        o2 = np.zeros(len(g.u))
        kernels.gather(
            g.u, g.v, self._table_r, self._table_a, self._half_r, self._half_a, float(OVERSAMPLE), float(r0),
            float(c0), np.ascontiguousarray(q1), np.ascontiguousarray(q2), o1, o2,
        )  # fmt: skip
        return o1, o2

    def window_for(self, g: Geometry, margin_px: int = 4) -> tuple[int, int, int, int]:
        """The frame's window (r0, c0, h, w) about the sites' pixels, the point spread and ``margin_px`` around."""
        r, a = self.radar.n_range, self.radar.n_azimuth
        pad_r, pad_a = int(math.ceil(self._half_r)) + margin_px, int(math.ceil(self._half_a)) + margin_px
        r0 = max(int(math.floor(g.u.min())) - pad_r, 0)
        c0 = max(int(math.floor(g.v.min())) - pad_a, 0)
        r1 = min(int(math.ceil(g.u.max())) + pad_r, r - 1)
        c1 = min(int(math.ceil(g.v.max())) + pad_a, a - 1)
        return r0, c0, max(r1 - r0 + 1, 1), max(c1 - c0 + 1, 1)
