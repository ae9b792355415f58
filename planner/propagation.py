"""The one adapter to skyfield and sgp4: time scales, Earth rotation, ephemerides, propagators.

Everything downstream sees numpy arrays only: times are seconds from a plan epoch
(``t_s``, a uniform TT-based count), vectors are GCRS (J2000 to 23 mas) in km and
km/s with shape (3, N). Three propagators share one interface, ``state(t_s)``:

* ``SecularJ2Trajectory``: mean elements with the J2 secular rates (analytic).
* ``NumericalJ2Trajectory``: two-body + J2 integrated with DOP853, then read
  anywhere in its span by quintic Hermite interpolation of the integrator's steps.
* ``SGP4Trajectory``: a TLE through SGP4, TEME rotated into GCRS.

Earth orientation (GCRS to ITRS) and the TEME rotation are taken from skyfield at
a coarse grid and interpolated, since a 10-day search needs them at ~10^5 times.
"""

from __future__ import annotations

import math
import os
import warnings
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from functools import lru_cache
from typing import Any, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from planner.constants import DAY_S, F_EARTH, J2, MU_EARTH_KM3_S2, OMEGA_EARTH_RAD_S, R_EARTH_KM
from planner.elements import Elements, elements_to_state, secular_state, state_to_elements
from planner.errors import PlannerError
from planner.integrator import hermite_state, integrate_j2
from planner.radar import Radar
from planner.tle import TLE

Vec = NDArray[np.float64]

_FRAME_GRID_S = 6 * 3600.0  # Earth-orientation sampling; see test_earth_rotation_against_skyfield


class Trajectory(Protocol):
    """Anything that gives GCRS position (km) and velocity (km/s) at seconds from the plan epoch."""

    def state(self, t_s: ArrayLike) -> tuple[Vec, Vec]: ...


def _skyfield_data_path(name: str) -> str:
    import skyfield_data

    return os.path.join(os.path.dirname(skyfield_data.__file__), "data", name)


@lru_cache(maxsize=1)
def timescale() -> Any:
    """Return skyfield's timescale with its built-in tables and IERS polar motion (no download).

    UT1-UTC and leap seconds are skyfield's built-in tables (daily from 1973 to its
    predictions' end, 2027-01-23 for skyfield 1.55; beyond that skyfield's long-term
    Delta-T model). Polar motion comes from the IERS ``finals2000A.all`` that the
    skyfield-data package ships (1973-01-02 to its predictions' end, 2026-08-29 for
    skyfield-data 7.0.0); outside those dates skyfield holds the nearest tabulated
    pole (an error of up to ~0.5 arcsec, ~15 m at the surface), and a plan says so in
    its notes (``earth_orientation_note``).
    """
    from skyfield.api import load
    from skyfield.data import iers

    ts = load.timescale(builtin=True)
    with open(_skyfield_data_path("finals2000A.all"), "rb") as f:
        finals = iers.parse_x_y_dut1_from_finals_all(f)
    iers.install_polar_motion_table(ts, finals)
    return ts


@lru_cache(maxsize=1)
def polar_motion_coverage() -> tuple[datetime, datetime]:
    """Return the first and last UTC moments of the polar-motion table (IERS finals2000A.all)."""
    ts = timescale()
    tt = ts.polar_motion_table[0]
    first, last = ts.tt_jd(np.array([tt[0], tt[-1]])).utc_datetime()
    return first, last


def earth_orientation_note(epoch: datetime, t0_s: float, t1_s: float) -> str | None:
    """Return a note when ``[t0_s, t1_s]`` after ``epoch`` leaves the polar-motion table, else None."""
    first, last = polar_motion_coverage()
    lo, hi = as_utc(epoch) + timedelta(seconds=t0_s), as_utc(epoch) + timedelta(seconds=t1_s)
    if first <= lo and hi <= last:
        return None
    return (
        f"polar motion is tabulated from {first:%Y-%m-%d} to {last:%Y-%m-%d} (IERS finals2000A.all in "
        "skyfield-data); outside that the nearest tabulated pole is held, worth up to ~15 m at the station "
        "and ~15 ms on the times of grazing passes"
    )


@lru_cache(maxsize=1)
def ephemeris() -> Any:
    """Return the de421 ephemeris shipped by the skyfield-data package (no download)."""
    from skyfield.api import Loader

    path = os.path.dirname(_skyfield_data_path("de421.bsp"))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return Loader(path, verbose=False)("de421.bsp")


def as_utc(epoch: datetime) -> datetime:
    """Return ``epoch`` as an aware UTC datetime (naive datetimes are taken as UTC)."""
    if epoch.tzinfo is None:
        return epoch.replace(tzinfo=UTC)
    return epoch.astimezone(UTC)


def skyfield_times(epoch: datetime, t_s: ArrayLike) -> Any:
    """Return skyfield Time for seconds after ``epoch`` (elapsed SI seconds)."""
    ts = timescale()
    t0 = ts.from_datetime(as_utc(epoch))
    offset_days = np.asarray(t_s, float) / DAY_S
    return ts.tt_jd(t0.whole, t0.tt_fraction + offset_days)


def seconds_between(epoch: datetime, moment: datetime) -> float:
    """Return elapsed seconds from ``epoch`` to ``moment`` (both UTC)."""
    ts = timescale()
    return float((ts.from_datetime(as_utc(moment)) - ts.from_datetime(as_utc(epoch))) * DAY_S)


_J2000_UTC = datetime(2000, 1, 1, 12, 0, tzinfo=UTC)


def _tai_minus_utc_s(moment: datetime) -> float:
    """TAI - UTC (s) at a UTC moment, from the leap-second table skyfield ships."""
    ts = timescale()
    jd = 2451545.0 + (as_utc(moment) - _J2000_UTC).total_seconds() / DAY_S
    k = int(np.searchsorted(ts.leap_dates, jd, side="right")) - 1
    return float(ts.leap_offsets[max(k, 0)])


def utc(epoch: datetime, t_s: float) -> datetime:
    """Return the UTC moment ``t_s`` elapsed SI seconds after ``epoch``: ``seconds_between``'s inverse.

    Elapsed seconds run through leap seconds, UTC's clock repeats one: 120 s after
    2016-12-31T23:59:00Z is 2017-01-01T00:00:59Z. A moment inside a leap second (23:59:60, which
    datetime cannot write) comes out as the next day's 00:00:00.
    """
    start = as_utc(epoch)
    guess = start + timedelta(seconds=float(t_s))
    offset = _tai_minus_utc_s(start)
    for _ in range(2):  # the offset at the answer decides the answer; twice settles it
        guess = start + timedelta(seconds=float(t_s) + offset - _tai_minus_utc_s(guess))
    return guess


def utc_many(epoch: datetime, t_s: ArrayLike) -> list[datetime]:
    """``utc`` of many elapsed times at once: where no leap second falls between the earliest and the latest (as
    nearly always), each is the epoch plus its seconds, shifted by the one offset; else ``utc`` of each."""
    t = np.atleast_1d(np.asarray(t_s, float))
    if not t.size:
        return []
    start = as_utc(epoch)
    first, last = utc(start, float(t.min())), utc(start, float(t.max()))
    if _tai_minus_utc_s(first) != _tai_minus_utc_s(last):
        return [utc(start, float(x)) for x in t]
    shift = _tai_minus_utc_s(start) - _tai_minus_utc_s(first)
    return [start + timedelta(seconds=float(x) + shift) for x in t]


def _rot_z(angle: Vec) -> Vec:
    """Return rotation matrices of shape (3, 3, N) about z by ``angle`` (skyfield's rot_z)."""
    c, s = np.cos(angle), np.sin(angle)
    zero, one = np.zeros_like(angle), np.ones_like(angle)
    return np.array([[c, -s, zero], [s, c, zero], [zero, zero, one]])


def mxv(m: Vec, v: Vec) -> Vec:
    """Multiply matrices (3, 3, ...) by vectors (3, ...), broadcasting over the trailing axes."""
    return np.einsum("ij...,j...->i...", m, v)


@dataclass(frozen=True, slots=True)
class Pole:
    """The Earth's rotation pole (CIP) in GCRS, a unit vector as a quadratic in time.

    ``p(t) = c[:, 0] + c[:, 1] dt + c[:, 2] dt^2`` with ``dt = t_s - t_mid_s``. The
    pole moves by precession (~20 arcsec a year) and nutation (9 arcsec over 18.6
    years, 0.6 arcsec semi-annual, 0.1 arcsec fortnightly); a quadratic over a span
    of up to 40 days leaves the fortnightly terms, under 1e-6 rad
    (tests/planner/test_propagation.py). J2 is applied about this axis: the GCRS z
    axis is 0.1355 deg from it in 2024, which moves a planned burn by 20-37 km.
    """

    t_mid_s: float
    c: Vec

    def at(self, t_s: ArrayLike) -> Vec:
        """Return the pole's GCRS unit vector, shape (3,) for a scalar time or (3, N)."""
        dt = np.asarray(t_s, float) - self.t_mid_s
        p = self.c[:, 0, None] + dt.reshape(-1) * (self.c[:, 1, None] + dt.reshape(-1) * self.c[:, 2, None])
        p = p / np.linalg.norm(p, axis=0)
        return p[:, 0] if np.ndim(t_s) == 0 else p


def pole_of_date(epoch: datetime, t0_s: float, t1_s: float) -> Pole:
    """Fit the CIP's GCRS direction over ``[t0_s, t1_s]`` seconds after ``epoch`` (skyfield's IAU 2000A M)."""
    t_mid = 0.5 * (t0_s + t1_s)
    half = max(0.5 * (t1_s - t0_s), 3600.0)
    grid = t_mid + half * np.cos(np.linspace(math.pi, 0.0, 25))  # Chebyshev nodes: a uniform error
    pole = skyfield_times(epoch, grid).M[2]  # third row of GCRS-to-true-of-date: the pole in GCRS
    coeffs = np.array([np.polyfit(grid - t_mid, pole[k], 2)[::-1] for k in range(3)])
    return Pole(t_mid, coeffs)


class EarthFrames:
    """GCRS-to-ITRS and TEME-to-GCRS rotations over ``[t0_s, t1_s]`` after ``epoch``.

    skyfield's ITRS rotation is Rz(-GAST) times the precession-nutation matrix M. M
    changes slowly, so it is sampled every 6 hours and interpolated by cubic splines;
    GAST is Earth rotation plus a slowly varying part, which is interpolated the same
    way (within 1e-9 rad of skyfield, tests/planner/test_propagation.py). Sampling is
    what costs: skyfield's IAU 2000A nutation is ~50 us a time. Polar motion W (IERS
    x, y and the TIO locator s') is applied last, ITRS = W Rz(-GAST) M, as skyfield's
    own ``itrs`` frame does; it changes by milliarcseconds a day, so the same spline serves.
    """

    def __init__(self, epoch: datetime, t0_s: float, t1_s: float) -> None:
        from scipy.interpolate import CubicSpline
        from skyfield.sgp4lib import TEME

        n = max(2, int(math.ceil((t1_s - t0_s) / _FRAME_GRID_S))) + 5
        self.epoch = epoch
        self.grid_s = t0_s - 2 * _FRAME_GRID_S + _FRAME_GRID_S * np.arange(n)
        t = skyfield_times(epoch, self.grid_s)
        gast_rad = np.unwrap(t.gast * (2.0 * math.pi / 24.0))
        self._gast0 = float(gast_rad[0])
        residual = gast_rad - self._gast0 - OMEGA_EARTH_RAD_S * (self.grid_s - self.grid_s[0])
        # Columns 0-8: precession-nutation M (GCRS to true of date); 9: the GAST residual;
        # 10-18: polar motion W (true of date, rotated by GAST, to ITRS).
        w = t.polar_motion_matrix().reshape(9, n)
        self._earth = CubicSpline(self.grid_s, np.vstack([t.M.reshape(9, n), residual, w]).T)
        self._teme = CubicSpline(self.grid_s, TEME.rotation_at(t).reshape(9, n).T)  # GCRS to TEME

    def _check(self, t_s: ArrayLike) -> Vec:
        t = np.atleast_1d(np.asarray(t_s, float))
        if t.size and (t.min() < self.grid_s[1] or t.max() > self.grid_s[-2]):
            raise PlannerError(f"time {t.min()}..{t.max()} s is outside the frame span", field="t_s")
        return t

    def _m_gast_w(self, t: Vec) -> tuple[Vec, Vec, Vec]:
        cols = self._earth(t)
        gast = self._gast0 + OMEGA_EARTH_RAD_S * (t - self.grid_s[0]) + cols[:, 9]
        return cols[:, :9].T.reshape(3, 3, t.size), gast, cols[:, 10:].T.reshape(3, 3, t.size)

    def gcrs_to_itrs(self, t_s: ArrayLike) -> Vec:
        """Return rotation matrices (3, 3, N) taking GCRS vectors to ITRS."""
        t = self._check(t_s)
        m, gast, w = self._m_gast_w(t)
        r = np.einsum("ij...,jk...->ik...", _rot_z(-gast), m)
        return np.einsum("ij...,jk...->ik...", w, r)

    def to_itrs(self, t_s: ArrayLike, r_gcrs_km: Vec) -> Vec:
        """Rotate GCRS vectors (3, N) at ``t_s`` into ITRS.

        The same rotation as ``gcrs_to_itrs`` without forming the matrices: precession-
        nutation first, then Earth rotation applied to x and y directly (the access
        search calls this thousands of times a plan).
        """
        t = self._check(t_s)
        m, gast, w = self._m_gast_w(t)
        tod = mxv(m, r_gcrs_km)
        c, s = np.cos(gast), np.sin(gast)
        return mxv(w, np.array([c * tod[0] + s * tod[1], c * tod[1] - s * tod[0], tod[2]]))

    def teme_to_gcrs(self, t_s: ArrayLike) -> Vec:
        """Return rotation matrices (3, 3, N) taking TEME vectors to GCRS."""
        t = self._check(t_s)
        return self._teme(t).T.reshape(3, 3, t.size).transpose(1, 0, 2)


@dataclass(frozen=True, slots=True)
class Station:
    """A ground site on the WGS-84 ellipsoid (degrees, metres) with an elevation mask.

    ``mask`` is the horizon the site sees, as (azimuth, elevation) pairs in degrees with the
    azimuths increasing in [0, 360), interpolated linearly (around north too); a satellite is
    in view above both it and ``min_elevation_deg``. ``refraction`` adds the atmosphere's
    bending to every elevation (``planner.access.refraction_deg``); off, elevations are geometric.
    """

    latitude_deg: float
    longitude_deg: float
    altitude_m: float = 0.0
    min_elevation_deg: float = 0.0
    max_range_km: float | None = None
    mask: tuple[tuple[float, float], ...] = ()
    refraction: bool = False
    # The fastest the antenna turns in azimuth (deg/s): a pass that needs more near the zenith is a keyhole.
    # 10 deg/s is a conservative rate for a large tracking antenna; give the site's own.
    max_azimuth_rate_deg_s: float = 10.0
    # The imaging radar at the site: its elevation limit, radar equation and coherent time (``planner.radar``).
    radar: Radar = field(default_factory=Radar)
    name: str = field(default="", compare=False)  # what a network's windows and candidates call it (a label)

    def itrs_km(self) -> Vec:
        """Return the site's ITRS position, shape (3,)."""
        lat, lon = math.radians(self.latitude_deg), math.radians(self.longitude_deg)
        e2 = F_EARTH * (2.0 - F_EARTH)
        n = R_EARTH_KM / math.sqrt(1.0 - e2 * math.sin(lat) ** 2)
        h = self.altitude_m / 1000.0
        return np.array(
            [
                (n + h) * math.cos(lat) * math.cos(lon),
                (n + h) * math.cos(lat) * math.sin(lon),
                (n * (1.0 - e2) + h) * math.sin(lat),
            ]
        )

    def enu_itrs(self) -> Vec:
        """Return the local east, north, up unit vectors as rows of a (3, 3) array (ITRS)."""
        lat, lon = math.radians(self.latitude_deg), math.radians(self.longitude_deg)
        sl, cl, so, co = math.sin(lat), math.cos(lat), math.sin(lon), math.cos(lon)
        return np.array([[-so, co, 0.0], [-sl * co, -sl * so, cl], [cl * co, cl * so, sl]])


def pole_frame(pole: Vec) -> Vec:
    """Return a rotation (3, 3) whose rows are GCRS axes x', y', z' with z' along ``pole``."""
    z = np.asarray(pole, float) / np.linalg.norm(pole)
    x = np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    return np.array([x, np.cross(z, x), z])


class SecularJ2Trajectory:
    """Mean elements propagated with the J2 secular rates; ``t_s`` counts from ``plan_epoch``.

    The node and perigee drift about ``pole`` (the Earth's axis, fixed at the middle of
    its fit; GCRS z if None): the elements, given in GCRS, are re-expressed about it,
    which rotates the conic and leaves a, e and M as they are.
    """

    def __init__(self, elements: Elements, plan_epoch: datetime, pole: Pole | None = None) -> None:
        self.elements = elements
        self.offset_s = seconds_between(elements.epoch, plan_epoch)
        self._rot = None if pole is None else pole_frame(pole.at(pole.t_mid_s))
        rad = elements.radians()
        if self._rot is not None:
            r0, v0 = elements_to_state(*rad)
            rad = tuple(float(x) for x in state_to_elements(self._rot @ r0, self._rot @ v0))  # type: ignore[assignment]
        self._rad = rad

    def state(self, t_s: ArrayLike) -> tuple[Vec, Vec]:
        t = np.atleast_1d(np.asarray(t_s, float)) + self.offset_s
        r, v = secular_state(self._rad, t)
        if self._rot is None:
            return r, v
        return self._rot.T @ r, self._rot.T @ v


def j2_acceleration(r_km: Vec, pole: Vec | None = None) -> Vec:
    """Return two-body plus J2 acceleration (km/s^2) at positions of shape (3,) or (3, N).

    J2 acts about ``pole`` (a unit vector, (3,) or (3, N), GCRS): the Earth's axis of
    date. Without it, about the GCRS z axis. In vector form the J2 term is
    ``f [(5 z^2 / r^2 - 1) r - 2 z p]`` with ``z = p . r``.
    """
    r_km = np.asarray(r_km, float)
    p = np.array([0.0, 0.0, 1.0]) if pole is None else np.asarray(pole, float)
    if r_km.ndim == 2 and p.ndim == 1:
        p = p[:, None]
    r2 = (r_km * r_km).sum(axis=0)
    r = np.sqrt(r2)
    k = -MU_EARTH_KM3_S2 / (r2 * r)
    f = 1.5 * J2 * MU_EARTH_KM3_S2 * R_EARTH_KM**2 / (r2 * r2 * r)
    z = (p * r_km).sum(axis=0)
    return k * r_km + f * ((5.0 * z * z / r2 - 1.0) * r_km - 2.0 * z * p)


_F = 1.5 * J2 * MU_EARTH_KM3_S2 * R_EARTH_KM**2


class NumericalJ2Trajectory:
    """Two-body + J2 motion integrated once with DOP853, then interpolated anywhere in its span.

    The integration is one compiled call, force model and stepping alike (``planner.integrator``); it
    agrees with scipy's Fortran DOP853 and with the tests' own integrators (tests/planner/test_propagation.py).
    The integrator's own steps are kept and read back by quintic Hermite interpolation of position,
    velocity and acceleration, accurate to well under a metre.
    """

    def __init__(
        self,
        r0_km: ArrayLike,
        v0_km_s: ArrayLike,
        t0_s: float,
        t1_s: float,
        rtol: float = 1e-10,
        pole: Pole | None = None,
    ) -> None:
        if not (math.isfinite(t0_s) and math.isfinite(t1_s)):
            raise PlannerError("propagation span must be finite", field="t_s")
        y0 = np.concatenate([np.asarray(r0_km, float), np.asarray(v0_km_s, float)])
        self.t0_s, self.t1_s = float(t0_s), float(t1_s)
        if t1_s == t0_s:
            t, y = np.array([t0_s, t0_s + 1e-9]), np.array([y0, y0]).T
        else:
            steps_t, steps_y, status = integrate_j2(
                y0,
                t0_s,
                t1_s,
                rtol,
                rtol * 1e-2,
                None if pole is None else pole.c,
                0.0 if pole is None else pole.t_mid_s,
            )
            if status != 0 or not np.all(np.isfinite(steps_y)):
                raise PlannerError("numerical propagation failed (orbit decayed or diverged)", field="elements")
            t, y = steps_t, steps_y.T
        order = np.argsort(t)
        self._t = t[order]
        self._r = y[:3, order]
        self._v = y[3:, order]
        self.pole = pole
        self._a = j2_acceleration(self._r, None if pole is None else pole.at(self._t))

    @classmethod
    def from_elements(
        cls, elements: Elements, plan_epoch: datetime, t0_s: float, t1_s: float, pole: Pole | None = None
    ) -> NumericalJ2Trajectory:
        """Integrate osculating ``elements`` over ``[t0_s, t1_s]`` seconds after ``plan_epoch``.

        J2 acts about ``pole``; by default the pole of date fitted over the integrated span.
        """
        r0, v0 = elements_to_state(*elements.radians())
        offset = seconds_between(plan_epoch, elements.epoch)
        lo, hi = min(t0_s, offset), max(t1_s, offset)
        if pole is None:
            pole = pole_of_date(plan_epoch, lo, hi)
        # Integrate forward and backward from the element epoch to cover the span.
        fwd = cls(r0, v0, offset, hi, pole=pole) if hi > offset else None
        bwd = cls(r0, v0, offset, lo, pole=pole) if lo < offset else None
        if fwd is None and bwd is None:
            return cls(r0, v0, offset, offset, pole=pole)
        if bwd is None:
            assert fwd is not None
            return fwd
        if fwd is None:
            return bwd
        return fwd._joined(bwd)

    def _joined(self, other: NumericalJ2Trajectory) -> NumericalJ2Trajectory:
        joined = object.__new__(NumericalJ2Trajectory)
        t = np.concatenate([other._t, self._t])
        order = np.argsort(t, kind="stable")
        keep = np.concatenate([[True], np.diff(t[order]) > 0])
        idx = order[keep]
        joined._t = t[idx]
        joined._r = np.concatenate([other._r, self._r], axis=1)[:, idx]
        joined._v = np.concatenate([other._v, self._v], axis=1)[:, idx]
        joined._a = np.concatenate([other._a, self._a], axis=1)[:, idx]
        joined.pole = self.pole
        joined.t0_s, joined.t1_s = float(joined._t[0]), float(joined._t[-1])
        return joined

    def state(self, t_s: ArrayLike) -> tuple[Vec, Vec]:
        t = np.atleast_1d(np.asarray(t_s, float))
        if t.size and (t.min() < self._t[0] - 1e-6 or t.max() > self._t[-1] + 1e-6):
            raise PlannerError(
                f"time {t.min():.3f}..{t.max():.3f} s is outside the propagated span "
                f"{self._t[0]:.3f}..{self._t[-1]:.3f} s",
                field="t_s",
            )
        return hermite_state(self._t, self._r, self._v, self._a, t)


def propagate_j2(
    r0_km: ArrayLike, v0_km_s: ArrayLike, t0_s: float, t1_s: float, pole: Pole | None = None
) -> tuple[Vec, Vec]:
    """Return the two-body + J2 state at ``t1_s`` from ``(r0, v0)`` at ``t0_s`` (shape (3,)); J2 about ``pole``."""
    traj = NumericalJ2Trajectory(r0_km, v0_km_s, t0_s, t1_s, pole=pole)
    r, v = traj.state(t1_s)
    return r[:, 0], v[:, 0]


class SGP4Trajectory:
    """A TLE propagated by SGP4 (vectorised), rotated from TEME into GCRS: the catalogue of one."""

    def __init__(self, tle: TLE, plan_epoch: datetime, frames: EarthFrames) -> None:
        self.tle = tle
        self.frames = frames
        self._one = SGP4Catalogue([tle], plan_epoch, frames)
        self.satrec = self._one.satrecs[0]

    def state(self, t_s: ArrayLike) -> tuple[Vec, Vec]:
        t = np.atleast_1d(np.asarray(t_s, float))
        return self._one.state(t, np.zeros(t.size, np.int64))


class SGP4Catalogue:
    """Many TLEs propagated by SGP4 together, rotated from TEME into GCRS at once: ``state(t, j)`` is satellite
    ``j[m]``'s state at ``t[m]`` (the keyed state of ``planner.access.pair_access``)."""

    def __init__(self, tles: list[TLE], plan_epoch: datetime, frames: EarthFrames) -> None:
        from sgp4.api import Satrec, jday

        self.tles = tles
        self.satrecs = [Satrec.twoline2rv(t.line1, t.line2) for t in tles]
        self.frames = frames
        e = as_utc(plan_epoch)
        self._jd_whole, self._jd_frac0 = jday(e.year, e.month, e.day, e.hour, e.minute, e.second + e.microsecond * 1e-6)

    def state(self, t_s: ArrayLike, j: NDArray[np.int64]) -> tuple[Vec, Vec]:
        t = np.atleast_1d(np.asarray(t_s, float))
        r = np.empty((t.size, 3))
        v = np.empty((t.size, 3))
        order = np.argsort(j, kind="stable")
        bounds = np.flatnonzero(np.diff(j[order])) + 1
        fr_all = self._jd_frac0 + t / DAY_S
        for part in np.split(order, bounds):
            if not part.size:
                continue
            err, r[part], v[part] = self.satrecs[int(j[part[0]])].sgp4_array(
                np.full(part.size, self._jd_whole), fr_all[part]
            )
            if np.any(err):
                from sgp4.api import SGP4_ERRORS

                code = int(err[err != 0][0])
                which = "this TLE" if len(self.satrecs) == 1 else f"element set {int(j[part[0]])}"
                raise PlannerError(f"SGP4 failed for {which}: {SGP4_ERRORS.get(code, code)}", field="tle")
        rot = self.frames.teme_to_gcrs(t)
        return mxv(rot, r.T), mxv(rot, v.T)
