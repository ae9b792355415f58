"""Keplerian elements: conversions, J2 secular rates and the cost of changing Ha and Hp.

Shape convention (skyfield's): a vector has shape ``(3,)`` and a series of vectors
``(3, N)``. Angles inside the functions are radians unless the name says ``_deg``.
Heights are above the equatorial radius ``R_EARTH_KM``, as in the paper's Table 1.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from datetime import datetime

import numpy as np
from numpy.typing import ArrayLike, NDArray

from planner.constants import J2, MIN_PERIGEE_HEIGHT_KM, MU_EARTH_KM3_S2, R_EARTH_KM
from planner.errors import ElementsError

TAU = 2.0 * math.pi


@dataclass(frozen=True, slots=True)
class Elements:
    """Orbital elements at an epoch in the paper's Table 1 form (heights in km, angles in degrees).

    The elements are GCRS/J2000 and carry no reading of their own: the plan's
    ``PlanOptions.reading`` says how they are taken, ``"osculating"`` (the instantaneous
    two-body orbit at the epoch, propagated numerically with J2) or ``"mean"`` (mean
    elements propagated with the J2 secular rates).
    """

    epoch: datetime
    ha_km: float
    hp_km: float
    inclination_deg: float
    raan_deg: float
    arg_perigee_deg: float
    mean_anomaly_deg: float

    def __post_init__(self) -> None:
        validate_elements(self)

    @property
    def a_km(self) -> float:
        return float(semi_major_axis_km(self.ha_km, self.hp_km))

    @property
    def e(self) -> float:
        return float(eccentricity(self.ha_km, self.hp_km))

    def with_heights(self, delta_ha_km: float, delta_hp_km: float) -> Elements:
        """Return these elements with apogee and perigee heights changed.

        When the new "apogee" falls below the new perigee the two apsides swap, so
        the argument of perigee and the mean anomaly move by 180 degrees.
        """
        ha, hp = self.ha_km + delta_ha_km, self.hp_km + delta_hp_km
        if ha >= hp:
            return replace(self, ha_km=ha, hp_km=hp)
        return replace(
            self,
            ha_km=hp,
            hp_km=ha,
            arg_perigee_deg=(self.arg_perigee_deg + 180.0) % 360.0,
            mean_anomaly_deg=(self.mean_anomaly_deg + 180.0) % 360.0,
        )

    def radians(self) -> tuple[float, float, float, float, float, float]:
        """Return ``(a_km, e, i, raan, argp, M)`` with the angles in radians."""
        return (
            self.a_km,
            self.e,
            math.radians(self.inclination_deg),
            math.radians(self.raan_deg),
            math.radians(self.arg_perigee_deg),
            math.radians(self.mean_anomaly_deg),
        )


def validate_elements(el: Elements) -> None:
    """Raise ElementsError naming the field when the elements describe no usable orbit."""
    for name in ("ha_km", "hp_km", "inclination_deg", "raan_deg", "arg_perigee_deg", "mean_anomaly_deg"):
        value = getattr(el, name)
        if not math.isfinite(value):
            raise ElementsError(f"{name} must be a finite number, got {value}", field=name)
    if el.hp_km < MIN_PERIGEE_HEIGHT_KM:
        raise ElementsError(
            f"perigee height {el.hp_km} km is below {MIN_PERIGEE_HEIGHT_KM} km: the orbit would decay",
            field="hp_km",
        )
    if el.ha_km < el.hp_km:
        raise ElementsError(
            f"apogee height {el.ha_km} km is below perigee height {el.hp_km} km: swap them", field="ha_km"
        )
    if el.ha_km > 1.0e6:
        raise ElementsError(f"apogee height {el.ha_km} km is beyond 1e6 km: not an Earth orbit", field="ha_km")
    if not 0.0 <= el.inclination_deg <= 180.0:
        raise ElementsError(f"inclination {el.inclination_deg} deg is outside [0, 180]", field="inclination_deg")


def semi_major_axis_km(ha_km: ArrayLike, hp_km: ArrayLike) -> NDArray[np.float64]:
    """Return the semi-major axis from apogee and perigee heights above R_EARTH_KM.

    >>> float(semi_major_axis_km(700.0, 600.0))
    7028.137
    """
    return R_EARTH_KM + 0.5 * (np.asarray(ha_km, float) + np.asarray(hp_km, float))


def eccentricity(ha_km: ArrayLike, hp_km: ArrayLike) -> NDArray[np.float64]:
    """Return the eccentricity from apogee and perigee heights.

    >>> round(float(eccentricity(700.0, 600.0)), 6)
    0.007114
    """
    ha = np.asarray(ha_km, float)
    hp = np.asarray(hp_km, float)
    return (ha - hp) / (2.0 * R_EARTH_KM + ha + hp)


def raan_rate_change_rad_s(
    a_km: float, e: float, inclination_rad: float, delta_ha_km: ArrayLike, delta_hp_km: ArrayLike
) -> NDArray[np.float64]:
    """Return how much the J2 nodal rate (rad/s) changes when Ha and Hp change by the given km.

    This is the whole dependence of the node line on (dHa, dHp): the plane turns
    about the Earth's axis by this rate times the time since the change.
    """
    ha0 = a_km * (1.0 + e) - R_EARTH_KM
    hp0 = a_km * (1.0 - e) - R_EARTH_KM
    ha = ha0 + np.asarray(delta_ha_km, float)
    hp = hp0 + np.asarray(delta_hp_km, float)
    base, _, _ = j2_secular_rates(a_km, e, inclination_rad)
    new, _, _ = j2_secular_rates(semi_major_axis_km(ha, hp), eccentricity(ha, hp), inclination_rad)
    return new - base


def mean_motion_rad_s(a_km: ArrayLike) -> NDArray[np.float64]:
    """Return the Keplerian mean motion sqrt(mu / a^3) in rad/s."""
    a = np.asarray(a_km, float)
    return np.sqrt(MU_EARTH_KM3_S2 / a**3)


def j2_secular_rates(
    a_km: ArrayLike, e: ArrayLike, inclination_rad: ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Return the J2 secular rates ``(raan_dot, argp_dot, M_dot)`` in rad/s.

    The first-order rates of DESIGN.md section 2; the RAAN rate carries its physical
    minus sign (the paper prints it without). Works on scalars and on arrays.

    >>> raan_dot, _, _ = j2_secular_rates(7028.137, 0.007114, np.radians(43.0))
    >>> round(float(np.degrees(raan_dot) * 86400.0), 3)  # deg/day, westward for prograde orbits
    -5.189
    """
    a = np.asarray(a_km, float)
    ecc = np.asarray(e, float)
    i = np.asarray(inclination_rad, float)
    n = mean_motion_rad_s(a)
    p = a * (1.0 - ecc**2)
    k = n * J2 * (R_EARTH_KM / p) ** 2
    cos_i = np.cos(i)
    raan_dot = -1.5 * k * cos_i
    argp_dot = 0.75 * k * (5.0 * cos_i**2 - 1.0)
    m_dot = n + 0.75 * k * np.sqrt(1.0 - ecc**2) * (3.0 * cos_i**2 - 1.0)
    return raan_dot, argp_dot, m_dot


def eccentric_anomaly(mean_anomaly_rad: ArrayLike, e: ArrayLike) -> NDArray[np.float64]:
    """Solve Kepler's equation M = E - e sin E for E (Newton, elliptic orbits only)."""
    m = np.mod(np.asarray(mean_anomaly_rad, float), TAU)
    ecc = np.asarray(e, float)
    big_e = np.where(ecc < 0.8, m, np.pi)
    for _ in range(50):
        f = big_e - ecc * np.sin(big_e) - m
        step = f / (1.0 - ecc * np.cos(big_e))
        big_e = big_e - step
        if np.all(np.abs(step) < 1e-14):
            break
    return big_e


def orbit_normal(inclination_rad: ArrayLike, raan_rad: ArrayLike) -> NDArray[np.float64]:
    """Return the unit orbit normal [sin i sin O, -sin i cos O, cos i], shape (3,) or (3, N).

    This is the paper's [sin i cos theta, sin i sin theta, cos i] with theta = O - pi/2.
    """
    i = np.asarray(inclination_rad, float)
    raan = np.asarray(raan_rad, float)
    theta = raan - 0.5 * np.pi
    return np.array([np.sin(i) * np.cos(theta), np.sin(i) * np.sin(theta), np.cos(i) * np.ones_like(theta)])


def elements_to_state(
    a_km: ArrayLike,
    e: ArrayLike,
    inclination_rad: ArrayLike,
    raan_rad: ArrayLike,
    argp_rad: ArrayLike,
    mean_anomaly_rad: ArrayLike,
    mu_km3_s2: float = MU_EARTH_KM3_S2,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Return position (km) and velocity (km/s) of elliptic two-body elements.

    Every argument may be a scalar or an array (broadcast together); the result has
    shape (3,) or (3, N) in the frame the elements are referred to.
    """
    a, ecc, i, raan, argp, m = np.broadcast_arrays(
        *(np.asarray(x, float) for x in (a_km, e, inclination_rad, raan_rad, argp_rad, mean_anomaly_rad))
    )
    big_e = eccentric_anomaly(m, ecc)
    cos_e, sin_e = np.cos(big_e), np.sin(big_e)
    root = np.sqrt(1.0 - ecc**2)
    # Perifocal coordinates.
    x_p = a * (cos_e - ecc)
    y_p = a * root * sin_e
    r = a * (1.0 - ecc * cos_e)
    factor = np.sqrt(mu_km3_s2 * a) / r
    vx_p = -factor * sin_e
    vy_p = factor * root * cos_e
    co, so = np.cos(raan), np.sin(raan)
    cw, sw = np.cos(argp), np.sin(argp)
    ci, si = np.cos(i), np.sin(i)
    p_vec = np.array([co * cw - so * sw * ci, so * cw + co * sw * ci, sw * si])
    q_vec = np.array([-co * sw - so * cw * ci, -so * sw + co * cw * ci, cw * si])
    return p_vec * x_p + q_vec * y_p, p_vec * vx_p + q_vec * vy_p


def state_to_elements(
    r_km: ArrayLike, v_km_s: ArrayLike, mu_km3_s2: float = MU_EARTH_KM3_S2
) -> tuple[NDArray[np.float64], ...]:
    """Return ``(a_km, e, i, raan, argp, M)`` (radians) of an elliptic two-body state.

    Accepts shape (3,) or (3, N). Equatorial or circular orbits get the conventional
    zero for the undefined angles.
    """
    r = np.asarray(r_km, float)
    v = np.asarray(v_km_s, float)
    h = np.cross(r, v, axis=0)
    r_norm = np.linalg.norm(r, axis=0)
    v2 = (v * v).sum(axis=0)
    h_norm = np.linalg.norm(h, axis=0)
    node = np.array([-h[1], h[0], np.zeros_like(h[0])])
    node_norm = np.linalg.norm(node, axis=0)
    e_vec = ((v2 - mu_km3_s2 / r_norm) * r - (r * v).sum(axis=0) * v) / mu_km3_s2
    ecc = np.linalg.norm(e_vec, axis=0)
    energy = 0.5 * v2 - mu_km3_s2 / r_norm
    a = -mu_km3_s2 / (2.0 * energy)
    i = np.arccos(np.clip(h[2] / h_norm, -1.0, 1.0))
    raan = np.mod(np.arctan2(node[1], node[0]), TAU)
    safe_node = np.where(node_norm > 1e-12, node_norm, 1.0)
    safe_e = np.where(ecc > 1e-12, ecc, 1.0)
    argp = np.arccos(np.clip((node * e_vec).sum(axis=0) / (safe_node * safe_e), -1.0, 1.0))
    argp = np.where(e_vec[2] < 0.0, TAU - argp, argp)
    argp = np.where((ecc > 1e-12) & (node_norm > 1e-12), argp, 0.0)
    # True anomaly measured from perigee (or from the node for circular orbits).
    ref = np.where(ecc > 1e-12, e_vec / safe_e, node / safe_node)
    nu = np.arccos(np.clip((ref * r).sum(axis=0) / r_norm, -1.0, 1.0))
    nu = np.where((r * v).sum(axis=0) < 0.0, TAU - nu, nu)
    big_e = 2.0 * np.arctan2(np.sqrt(1.0 - ecc) * np.sin(nu / 2.0), np.sqrt(1.0 + ecc) * np.cos(nu / 2.0))
    m = np.mod(big_e - ecc * np.sin(big_e), TAU)
    return a, ecc, i, raan, argp, m


def elements_of_state(r_km: ArrayLike, v_km_s: ArrayLike, epoch: datetime) -> Elements:
    """The osculating elements of an elliptic GCRS state (shape (3,)) in Table 1 form, as elements of ``epoch``."""
    a, e, i, raan, argp, m = (float(x) for x in state_to_elements(r_km, v_km_s))
    return Elements(
        epoch,
        a * (1 + e) - R_EARTH_KM,
        a * (1 - e) - R_EARTH_KM,
        math.degrees(i),
        math.degrees(raan),
        math.degrees(argp),
        math.degrees(m),
    )


def secular_state(
    elements: tuple[float, float, float, float, float, float], t_s: ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Propagate mean elements ``(a, e, i, raan, argp, M)`` with J2 secular rates.

    Returns position (km) and velocity (km/s) of shape (3, N) at ``t_s`` seconds after
    the elements' epoch (the two-body orbit of the mean elements at each time).
    """
    a, e, i, raan0, argp0, m0 = elements
    t = np.asarray(t_s, float)
    raan_dot, argp_dot, m_dot = j2_secular_rates(a, e, i)
    return elements_to_state(a, e, i, raan0 + raan_dot * t, argp0 + argp_dot * t, m0 + m_dot * t)


def height_change_dv_km_s(a_km: float, e: float, delta_ha_km: ArrayLike, delta_hp_km: ArrayLike) -> NDArray[np.float64]:
    """Return the two-impulse tangential Delta-v (km/s) that changes Ha and Hp by the given amounts.

    One burn at perigee moves the apogee, one at the new apogee moves the perigee
    (vis-viva, two-body). Works on arrays of height changes.

    >>> round(float(height_change_dv_km_s(7000.0, 0.0, 10.0, 10.0)) * 1000.0, 2)  # m/s
    5.38
    """
    mu = MU_EARTH_KM3_S2
    rp0 = a_km * (1.0 - e)
    ra0 = a_km * (1.0 + e)
    ra1 = ra0 + np.asarray(delta_ha_km, float)
    rp1 = rp0 + np.asarray(delta_hp_km, float)

    def speed(r: NDArray[np.float64] | float, a: NDArray[np.float64] | float) -> NDArray[np.float64]:
        return np.sqrt(mu * (2.0 / np.asarray(r) - 1.0 / np.asarray(a)))

    dv1 = np.abs(speed(rp0, 0.5 * (rp0 + ra1)) - speed(rp0, a_km))
    dv2 = np.abs(speed(ra1, 0.5 * (rp1 + ra1)) - speed(ra1, 0.5 * (rp0 + ra1)))
    return dv1 + dv2
