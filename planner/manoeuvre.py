"""Algorithm 1, Step 2: the in-plane phasing burn that brings the observer to the target on time.

One impulsive burn, one or two observer revolutions before ``T_access``, puts the
observer on a Lambert transfer to the target's position at ``T_access``. The
two-body Lambert solution is then corrected for J2 by shooting: the transfer is
propagated numerically, the arrival error is added to the aim point, and Lambert
is solved again, until the numerically propagated arrival is within ``tol_km``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from planner.constants import MU_EARTH_KM3_S2
from planner.errors import LambertError, PlannerError
from planner.lambert import lambert, max_revolutions
from planner.propagation import NumericalJ2Trajectory, Pole, Trajectory, propagate_j2
from planner.search import grid_maxima

Vec = NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class Phasing:
    """The phasing burn and its numerical verification.

    ``dv_km_s`` is the impulse in GCRS, ``dv_rtn_km_s`` the same in the observer's
    radial / along-track / cross-track frame at the burn. ``two_body_miss_km`` is
    how far the plain Lambert burn lands from the target once J2 is included, and
    ``miss_km`` the verified distance from the aim point after the J2 correction. The aim
    point is the target's position plus ``standoff_km_vec`` (GCRS, km) at ``t_access_s``:
    a stand-off beside the target, never the target itself (that would be a collision course).
    ``v_departure_km_s`` is the observer's velocity just after the burn.
    """

    t_burn_s: float
    t_access_s: float
    revolutions_before: int
    lambert_revolutions: int
    low_path: bool
    dv_km_s: Vec
    dv_rtn_km_s: Vec
    dv_total_km_s: float
    two_body_miss_km: float
    miss_km: float
    corrections: int
    r_observer_km: Vec
    v_relative_km_s: Vec
    v_departure_km_s: Vec
    standoff_km_vec: Vec


def rtn_matrix(r_km: Vec, v_km_s: Vec) -> Vec:
    """Return the rows R (radial), T (along-track), N (orbit normal) at a state, shape (3, 3)."""
    rhat = r_km / np.linalg.norm(r_km)
    n = np.cross(r_km, v_km_s)
    nhat = n / np.linalg.norm(n)
    return np.array([rhat, np.cross(nhat, rhat), nhat])


def period_s(r_km: Vec, v_km_s: Vec) -> float:
    """Return the two-body period of a state (s)."""
    energy = 0.5 * float(v_km_s @ v_km_s) - MU_EARTH_KM3_S2 / float(np.linalg.norm(r_km))
    a = -MU_EARTH_KM3_S2 / (2.0 * energy)
    return 2.0 * math.pi * math.sqrt(a**3 / MU_EARTH_KM3_S2)


def lambert_options(r1: Vec, v1: Vec, r2: Vec, tof_s: float) -> list[tuple[float, Vec, int, bool]]:
    """Every Lambert transfer from (r1, v1) to r2 in ``tof_s``: (two-body cost, departure velocity, revolutions,
    low branch), cheapest first."""
    found = []
    h = np.cross(r1, v1)
    for m in range(0, max_revolutions(r1, r2, tof_s) + 1):
        for low in (True, False) if m else (True,):
            try:
                sol = lambert(r1, r2, tof_s, m, low, prograde_normal=h)
            except LambertError:
                continue
            found.append((float(np.linalg.norm(sol.v1_km_s - v1)), sol.v1_km_s, m, low))
    return sorted(found, key=lambda o: o[0])


def best_lambert(r1: Vec, v1: Vec, r2: Vec, tof_s: float) -> tuple[Vec, int, bool]:
    """Return the departure velocity, revolutions and branch of the cheapest transfer from (r1, v1) to r2."""
    found = lambert_options(r1, v1, r2, tof_s)
    if not found:
        raise LambertError("no Lambert transfer found for this geometry", field="phasing")
    _, v_dep, m, low = found[0]
    return v_dep, m, low


# Burn options (revolutions before, Lambert branch) within this factor of the cheapest two-body one are each
# corrected for J2 and compared on their corrected cost: J2 moves a 1-2 revolution transfer's cost by a few percent,
# enough to reorder options that two-body cost puts close (design/measurements.md, "The cheapest option after J2").
NEAR_TWO_BODY = 1.25


def phase(
    observer: Trajectory,
    target: Trajectory,
    t_access_s: float,
    revolutions_before: tuple[int, ...] = (1, 2),
    t_earliest_burn_s: float = 0.0,
    tol_km: float = 1e-3,
    max_corrections: int = 8,
    pole: Pole | None = None,
    standoff_km: float = 0.0,
    sun_km: Vec | None = None,
    standoff_rounds: int = 2,
    propagate: bool = True,
) -> Phasing:
    """Plan the phasing burn, one of ``revolutions_before`` revolutions before, and verify it numerically.

    Every burn option (revolutions before, Lambert revolutions and branch) whose two-body cost is within
    ``NEAR_TWO_BODY`` of the cheapest is corrected for J2, and the cheapest corrected one is taken: two-body cost
    alone can pick an option that costs more once J2 is in.

    The verification integrates two-body + J2 about ``pole`` (the Earth's axis of date;
    GCRS z if None) from the burn to ``t_access_s``. The aim point lies ``standoff_km``
    from the target (``standoff_direction``, toward the Sun at ``sun_km`` where it can);
    its side follows the relative velocity, which follows the aim, so it is set
    ``standoff_rounds`` times. ``propagate`` off gives the plain two-body Lambert burn
    without any integration (its relative velocity is Lambert's arrival velocity's, within
    about a percent of the integrated one's; misses NaN): a screening's cheap first look.

    Raises PlannerError if every option would burn before ``t_earliest_burn_s``.
    """
    r_t, v_t = target.state(t_access_s)
    r2, v2_target = r_t[:, 0], v_t[:, 0]
    r_o, v_o = observer.state(t_access_s)
    period = period_s(r_o[:, 0], v_o[:, 0])
    options = []
    for k in revolutions_before:
        t_burn = t_access_s - k * period
        if t_burn < t_earliest_burn_s:
            continue
        r1s, v1s = observer.state(t_burn)
        r1, v1 = r1s[:, 0], v1s[:, 0]
        for cost, v_dep, m, low in lambert_options(r1, v1, r2, k * period):
            options.append((cost, k, t_burn, r1, v1, v_dep, m, low))
    if not options:
        if any(t_access_s - k * period >= t_earliest_burn_s for k in revolutions_before):
            raise LambertError("no Lambert transfer found for this geometry", field="phasing")
        raise PlannerError(
            f"the access at {t_access_s:.0f} s is too early for a burn {min(revolutions_before)} revolution(s) "
            "before it; start the search earlier",
            field="start",
        )
    options.sort(key=lambda o: o[0])
    if not propagate:  # the plain Lambert burn: its arrival velocity, no integration, no miss measured
        _, k, t_burn, r1, v1, v_dep, m, low = options[0]
        h = np.cross(r1, v1)
        v_end = lambert(r1, r2, t_access_s - t_burn, m, low, prograde_normal=h).v2_km_s
        side = standoff_direction(r2, v_end - v2_target, sun_km) if standoff_km > 0.0 else np.zeros(3)
        offset = standoff_km * side
        r_end = r2 + offset
        two_body_miss = miss = math.nan
        corrections = 0
    else:  # every option nearly as cheap as the cheapest, corrected for J2; the cheapest corrected one flown
        near = [o for o in options if o[0] <= NEAR_TWO_BODY * options[0][0]]
        flown = []
        failed: PlannerError | None = None
        for _, k, t_burn, r1, v1, v_dep, m, low in near:
            h = np.cross(r1, v1)
            offset = np.zeros(3)
            aim = r2.copy()
            corrections = 0
            try:
                r_end, v_end = propagate_j2(r1, v_dep, t_burn, t_access_s, pole)
                two_body_miss = float(np.linalg.norm(r_end - r2))
                # The stand-off side depends on the relative velocity, which depends on the aim: twice is enough.
                for _ in range(standoff_rounds if standoff_km > 0.0 else 1):
                    if standoff_km > 0.0:
                        offset = standoff_km * standoff_direction(r2, v_end - v2_target, sun_km)
                    goal = r2 + offset
                    aim, v_dep, r_end, v_end, n = _shoot(
                        r1, h, aim, goal, v_dep, r_end, v_end, t_burn, t_access_s, m, low, pole, tol_km, max_corrections
                    )
                    corrections += n
            except PlannerError as exc:  # the corrected aim has no transfer on this branch (or it decays): gone
                failed = failed or exc
                continue
            miss = float(np.linalg.norm(r_end - (r2 + offset)))
            cost = float(np.linalg.norm(v_dep - v1))
            flown.append(
                (cost, k, t_burn, r1, v1, v_dep, m, low, r_end, v_end, offset, two_body_miss, miss, corrections)
            )
        if not flown:
            assert failed is not None
            raise failed
        # The cheapest corrected option; a full phasing (several corrections) prefers those that met the aim.
        flown.sort(key=lambda o: (max_corrections > 1 and o[12] > 10.0 * tol_km, o[0]))
        _, k, t_burn, r1, v1, v_dep, m, low, r_end, v_end, offset, two_body_miss, miss, corrections = flown[0]
    dv = v_dep - v1
    return Phasing(
        t_burn_s=t_burn,
        t_access_s=t_access_s,
        revolutions_before=k,
        lambert_revolutions=m,
        low_path=low,
        dv_km_s=dv,
        dv_rtn_km_s=rtn_matrix(r1, v1) @ dv,
        dv_total_km_s=float(np.linalg.norm(dv)),
        two_body_miss_km=two_body_miss,
        miss_km=miss,
        corrections=corrections,
        r_observer_km=r_end,
        v_relative_km_s=v_end - v2_target,
        v_departure_km_s=v_dep,
        standoff_km_vec=offset,
    )


def _shoot(
    r1: Vec,
    h: Vec,
    aim: Vec,
    goal: Vec,
    v_dep: Vec,
    r_end: Vec,
    v_end: Vec,
    t_burn_s: float,
    t_arrive_s: float,
    revolutions: int,
    low_path: bool,
    pole: Pole | None,
    tol_km: float,
    max_corrections: int,
) -> tuple[Vec, Vec, Vec, Vec, int]:
    """Correct a Lambert burn from ``r1`` for J2 by shooting: while the integrated arrival ``r_end`` misses ``goal``
    by over ``tol_km`` (at most ``max_corrections`` times), move the aim by the miss and solve Lambert again on the
    same branch. Returns the aim, the burn's departure velocity, the arrival state and the corrections made."""
    n = 0
    while np.linalg.norm(r_end - goal) > tol_km and n < max_corrections:
        aim = aim + (goal - r_end)
        v_dep = lambert(r1, aim, t_arrive_s - t_burn_s, revolutions, low_path, prograde_normal=h).v1_km_s
        r_end, v_end = propagate_j2(r1, v_dep, t_burn_s, t_arrive_s, pole)
        n += 1
    return aim, v_dep, r_end, v_end, n


def retarget(
    r1_km: Vec,
    v1_km_s: Vec,
    t_burn_s: float,
    goal_km: Vec,
    t_arrive_s: float,
    revolutions: int,
    low_path: bool,
    pole: Pole | None,
    tol_km: float = 1e-6,
) -> tuple[Vec, Vec, Vec]:
    """The burn from the exact state ``(r1, v1)`` at ``t_burn_s`` that arrives at ``goal_km`` at ``t_arrive_s``
    (two-body + J2), to ``tol_km``: Lambert on the branch given, corrected as ``phase`` corrects it (``_shoot``).
    Returns the impulse and the state on arrival. A campaign's burn computed from an interpolated state instead
    drifts the next scenes by km (design/measurements.md, "Chaining a campaign's burns")."""
    h = np.cross(r1_km, v1_km_s)
    goal = np.asarray(goal_km, float)
    v_dep = lambert(r1_km, goal, t_arrive_s - t_burn_s, revolutions, low_path, prograde_normal=h).v1_km_s
    r_end, v_end = propagate_j2(r1_km, v_dep, t_burn_s, t_arrive_s, pole)
    _, v_dep, r_end, v_end, _ = _shoot(
        r1_km, h, goal.copy(), goal, v_dep, r_end, v_end, t_burn_s, t_arrive_s, revolutions, low_path, pole, tol_km, 12
    )
    return np.asarray(v_dep - v1_km_s, float), r_end, v_end


def standoff_direction(r_target_km: Vec, v_relative_km_s: Vec, r_sun_km: Vec | None) -> Vec:
    """Return the unit vector from the target to the stand-off point, shape (3,).

    It is perpendicular to the relative velocity (so the stand-off is the closest
    approach of a straight fly-by) and, within that plane, points as near the Sun as
    it can, so the observer sees the target's lit side (the least phase angle). With
    the Sun along the relative velocity, or no Sun given, it points radially outward.
    """
    v = np.asarray(v_relative_km_s, float)
    vhat = v / np.linalg.norm(v)
    options = []
    if r_sun_km is not None:
        options.append(np.asarray(r_sun_km, float) - r_target_km)
    options.append(np.asarray(r_target_km, float))
    for s in options:
        d = s / np.linalg.norm(s)
        d = d - (d @ vhat) * vhat
        if np.linalg.norm(d) > 0.05:
            return d / np.linalg.norm(d)
    d = np.cross(vhat, [0.0, 0.0, 1.0])
    return d / np.linalg.norm(d)


@dataclass(frozen=True, slots=True)
class Encounter:
    """The observer's fly-by of the target, from the burn to one orbit after T_access.

    ``separation_km``, ``relative_speed_km_s`` and ``target_angular_rate_deg_s`` (the
    line of sight's rate as the observer sees it: what an optical tracker must follow)
    are at ``t_access_s``; ``closest_approach_km`` / ``closest_approach_s`` over the whole arc.
    """

    separation_km: float
    relative_speed_km_s: float
    target_angular_rate_deg_s: float
    closest_approach_km: float
    closest_approach_s: float
    arc: Trajectory | None = None  # the observer after the burn (the exports' ephemeris)
    relative: RelativeMotion | None = None  # the fly-by about T_access in the target's RTN frame


RELATIVE_HALF_S = 60.0  # the fly-by drawn from a minute before T_access to a minute after (about 800 km at 13 km/s)
RELATIVE_STEP_S = 1.0


@dataclass(frozen=True, slots=True)
class RelativeMotion:
    """Where the observer is relative to the target about T_access, in the target's own radial / along-track /
    orbit-normal frame at each moment (the Hill frame): ``t_s`` from T_access and ``rtn_km`` [3, N]."""

    t_s: Vec
    rtn_km: Vec


def relative_motion(
    observer: Callable[[Vec], tuple[Vec, Vec]],
    target: Callable[[Vec], tuple[Vec, Vec]],
    t_access_s: float,
    t_from_s: float,
    t_to_s: float,
    half_s: float = RELATIVE_HALF_S,
    step_s: float = RELATIVE_STEP_S,
) -> RelativeMotion:
    """The observer's position relative to the target, ``half_s`` either side of ``t_access_s`` (kept within
    ``t_from_s``..``t_to_s``, where the observer's arc is defined), each sample in the target's RTN frame then.
    ``observer`` and ``target`` give the states (km, km/s; [3, N]) at times [N] (a trajectory's ``state``)."""
    lo, hi = max(t_access_s - half_s, t_from_s), min(t_access_s + half_s, t_to_s)
    n = max(int(round((hi - lo) / step_s)), 1) + 1
    t = np.linspace(lo, hi, n)
    r_o, _ = observer(t)
    r_t, v_t = target(t)
    rel = r_o - r_t
    rtn = np.stack([rtn_matrix(r_t[:, k], v_t[:, k]) @ rel[:, k] for k in range(n)], axis=1)
    return RelativeMotion(t_s=t - t_access_s, rtn_km=rtn)


def encounter(
    phasing: Phasing, observer: Trajectory, target: Trajectory, t_end_s: float, pole: Pole | None
) -> Encounter:
    """Fly the phasing burn (two-body + J2 about ``pole``) to ``t_end_s`` and measure the encounter with ``target``.

    ``observer`` is the observer before the burn. The closest approach is found on 1-s
    samples of the distance, each sampled minimum refined (so a fast fly-by, 10 km/s,
    is timed to a millisecond).
    """
    r1, _ = observer.state(phasing.t_burn_s)
    t0 = phasing.t_burn_s
    arc = NumericalJ2Trajectory(r1[:, 0], phasing.v_departure_km_s, t0, t_end_s, pole=pole)

    def distance(t_s: Vec) -> Vec:
        r_o, _ = arc.state(t_s)
        r_t, _ = target.state(t_s)
        return np.linalg.norm(r_o - r_t, axis=0)

    t = np.linspace(t0, t_end_s, int(math.ceil(t_end_s - t0)) + 1)
    t_min, _ = grid_maxima(lambda x: -distance(x), t, -distance(t), 1e-4)
    cand_t = np.concatenate([t_min, [t[0], t[-1]]])
    cand_d = distance(cand_t)
    j = int(np.argmin(cand_d))
    r_o, v_o = arc.state(phasing.t_access_s)
    r_t, v_t = target.state(phasing.t_access_s)
    rho, rho_dot = (r_t - r_o)[:, 0], (v_t - v_o)[:, 0]
    rate = np.linalg.norm(np.cross(rho, rho_dot)) / float(rho @ rho)
    return Encounter(
        separation_km=float(np.linalg.norm(rho)),
        relative_speed_km_s=float(np.linalg.norm(rho_dot)),
        target_angular_rate_deg_s=math.degrees(rate),
        closest_approach_km=float(cand_d[j]),
        closest_approach_s=float(cand_t[j]),
        arc=arc,
        relative=relative_motion(arc.state, target.state, phasing.t_access_s, t0, t_end_s),
    )
