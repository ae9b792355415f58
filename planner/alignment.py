"""Algorithm 1, Step B: choose (dHa, dHp) so the node line of the two orbit planes meets the target.

The observer's plane after a change of apogee and perigee heights differs from
its unchanged plane only by the change of its J2 nodal rate: at time T it is the
unchanged plane turned about the Earth's axis by ``dRAAN_rate(dHa, dHp) * (T - t_ref)``.
So for every access moment T the turn that puts the target's position
into the observer's plane is found in closed form (two solutions, one for each
node), and the nodal-rate change it needs follows by division. The 2-D grid
search of the paper collapses to: which rate changes the (dHa, dHp) box can reach,
which access moments need one of them, and which point of the box gives it with
the smallest change. ``brute_force_miss`` keeps the paper's direct evaluation
for cross-checks and benchmarks.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from planner.access import AccessWindows
from planner.elements import raan_rate_change_rad_s
from planner.errors import SearchRangeError
from planner.propagation import Trajectory, pole_frame
from planner.search import bisect_roots

Vec = NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class HeightBox:
    """The admissible (dHa, dHp) grid: bounds and step in km."""

    dha_min_km: float = -50.0
    dha_max_km: float = 50.0
    dhp_min_km: float = -50.0
    dhp_max_km: float = 50.0
    step_km: float = 0.1

    def __post_init__(self) -> None:
        for name in ("dha_min_km", "dha_max_km", "dhp_min_km", "dhp_max_km", "step_km"):
            if not math.isfinite(getattr(self, name)):
                raise SearchRangeError(f"{name} must be finite", field=name)
        if self.dha_min_km > self.dha_max_km:
            raise SearchRangeError(f"dHa range {self.dha_min_km}..{self.dha_max_km} km is inverted", field="dha_min_km")
        if self.dhp_min_km > self.dhp_max_km:
            raise SearchRangeError(f"dHp range {self.dhp_min_km}..{self.dhp_max_km} km is inverted", field="dhp_min_km")
        if not self.step_km > 0.0:
            raise SearchRangeError(f"step {self.step_km} km must be positive", field="step_km")
        if self.grid_points > 25_000_000:
            raise SearchRangeError(
                f"the grid has {self.grid_points} points; at most 25,000,000 (widen the step)", field="step_km"
            )

    @property
    def dha_km(self) -> Vec:
        return _axis(self.dha_min_km, self.dha_max_km, self.step_km)

    @property
    def dhp_km(self) -> Vec:
        return _axis(self.dhp_min_km, self.dhp_max_km, self.step_km)

    @property
    def grid_points(self) -> int:
        na = int(math.floor((self.dha_max_km - self.dha_min_km) / self.step_km + 1e-9)) + 1
        nb = int(math.floor((self.dhp_max_km - self.dhp_min_km) / self.step_km + 1e-9)) + 1
        return na * nb

    def snap(self, dha: float, dhp: float) -> tuple[float, float]:
        """Return the grid point nearest to (dha, dhp), inside the box."""
        a = self.dha_km
        p = self.dhp_km
        return float(a[np.abs(a - dha).argmin()]), float(p[np.abs(p - dhp).argmin()])


def _axis(lo: float, hi: float, step: float) -> Vec:
    n = int(math.floor((hi - lo) / step + 1e-9)) + 1
    return lo + step * np.arange(n, dtype=np.float64)


@dataclass(frozen=True, slots=True)
class ObserverPlaneModel:
    """The observer's unchanged trajectory and what its nodal rate depends on.

    ``a_km``, ``e`` and ``inclination_rad`` are the observer's elements at ``t_ref_s``
    (the moment the height change is made, seconds from the plan epoch).
    """

    base: Trajectory
    a_km: float
    e: float
    inclination_rad: float
    t_ref_s: float
    pole: Vec | None = None  # the axis the node regresses about (GCRS unit vector); GCRS z if None

    def rate_change(self, dha_km: Vec | float, dhp_km: Vec | float) -> Vec:
        return raan_rate_change_rad_s(self.a_km, self.e, self.inclination_rad, dha_km, dhp_km)

    def normal(self, t_s: Vec, rate_change_rad_s: Vec | float = 0.0) -> Vec:
        """Return the observer's unit orbit normal (3, N) at ``t_s`` for a given nodal-rate change."""
        r, v = self.base.state(t_s)
        n = np.cross(r, v, axis=0)
        n /= np.linalg.norm(n, axis=0)
        turn = np.asarray(rate_change_rad_s) * (np.atleast_1d(t_s) - self.t_ref_s)
        c, s = np.cos(turn), np.sin(turn)
        if self.pole is None:
            return np.array([c * n[0] - s * n[1], s * n[0] + c * n[1], n[2]])
        # Rodrigues' rotation of n about the pole by the extra nodal turn.
        p = np.asarray(self.pole, float)[:, None]
        return c * n + s * np.cross(p, n, axis=0) + (1.0 - c) * p * (p * n).sum(axis=0)


@dataclass(frozen=True, slots=True)
class Candidate:
    """The best alignment of one pass: when, with which height changes, and how close.

    ``miss_km`` is |r_target| times the angle between the node line and the target
    (the paper's figure of merit). ``family_dha_km``/``family_dhp_km`` sample the
    curve of height changes that align the node line at the same moment;
    ``t_access_range_s`` is the span of this pass the box can align at all.
    """

    pass_index: int
    node: str
    t_access_s: float
    delta_ha_km: float
    delta_hp_km: float
    miss_km: float
    rate_change_rad_s: float
    t_access_range_s: tuple[float, float] | None
    family_dha_km: Vec
    family_dhp_km: Vec

    @property
    def change_km(self) -> float:
        return math.hypot(self.delta_ha_km, self.delta_hp_km)


def node_miss_km(r_target_km: Vec, v_target_km_s: Vec, n_obs: Vec) -> tuple[Vec, Vec]:
    """Return the miss (km) between the nearer node of the two planes and the target, and that node's sign.

    The target's plane comes from its own state (r x v). Shapes (3, N) -> (N,).
    """
    n_t = np.cross(r_target_km, v_target_km_s, axis=0)
    oc = np.cross(n_t, n_obs, axis=0)
    oc /= np.linalg.norm(oc, axis=0)
    r_norm = np.linalg.norm(r_target_km, axis=0)
    cos_angle = (oc * r_target_km).sum(axis=0) / r_norm
    sign = np.where(cos_angle >= 0.0, 1.0, -1.0)
    return r_norm * np.arccos(np.clip(np.abs(cos_angle), 0.0, 1.0)), sign


def _required_turns(u: Vec, n_b: Vec) -> tuple[Vec, Vec]:
    """Return the two z-rotations (rad, in (-pi, pi]) of normal ``n_b`` that make it perpendicular to ``u``."""
    a = n_b[0] * u[0] + n_b[1] * u[1]
    b = n_b[0] * u[1] - n_b[1] * u[0]
    c = n_b[2] * u[2]
    rr = np.hypot(a, b)
    psi = np.arctan2(b, a)
    half = np.arccos(np.clip(-c / np.where(rr > 0, rr, 1.0), -1.0, 1.0))
    return _wrap_pi(psi + half), _wrap_pi(psi - half)


def _wrap_pi(x: Vec) -> Vec:
    """Return angles wrapped into [-pi, pi)."""
    return np.mod(x + np.pi, 2.0 * np.pi) - np.pi


def _min_change_for_rate(model: ObserverPlaneModel, box: HeightBox, q: float) -> tuple[float, float]:
    """Return the grid point of the box nearest the origin whose nodal-rate change is ``q`` (rad/s)."""
    h = 1e-3
    ga = float((model.rate_change(h, 0.0) - model.rate_change(-h, 0.0)) / (2 * h))
    gp = float((model.rate_change(0.0, h) - model.rate_change(0.0, -h)) / (2 * h))
    g2 = ga * ga + gp * gp
    options = []
    x, y = q * ga / g2, q * gp / g2
    if box.dha_min_km <= x <= box.dha_max_km and box.dhp_min_km <= y <= box.dhp_max_km:
        options.append((x, y))
    for xa in (box.dha_min_km, box.dha_max_km):
        ya = (q - ga * xa) / gp
        if box.dhp_min_km <= ya <= box.dhp_max_km:
            options.append((xa, ya))
    for yp in (box.dhp_min_km, box.dhp_max_km):
        xp = (q - gp * yp) / ga
        if box.dha_min_km <= xp <= box.dha_max_km:
            options.append((xp, yp))
    if not options:
        options = [(box.dha_max_km, box.dhp_max_km) if q * ga > 0 else (box.dha_min_km, box.dhp_min_km)]
    x, y = min(options, key=lambda o: math.hypot(*o))
    # Newton along the gradient on the exact (non-linear) rate, then onto the grid.
    for _ in range(3):
        err = q - float(model.rate_change(x, y))
        x = float(np.clip(x + err * ga / g2, box.dha_min_km, box.dha_max_km))
        y = float(np.clip(y + err * gp / g2, box.dhp_min_km, box.dhp_max_km))
    return box.snap(x, y)


def height_family(model: ObserverPlaneModel, box: HeightBox, q: float, samples: int = 41) -> tuple[Vec, Vec]:
    """Return points (dHa, dHp) inside the box whose nodal-rate change equals ``q``: the one-parameter family."""
    dha = np.linspace(box.dha_min_km, box.dha_max_km, samples)
    h = 1e-3
    dhp = np.zeros_like(dha)
    for _ in range(6):
        f = model.rate_change(dha, dhp) - q
        df = (model.rate_change(dha, dhp + h) - model.rate_change(dha, dhp - h)) / (2 * h)
        dhp = dhp - f / df
    ok = (dhp >= box.dhp_min_km - 1e-9) & (dhp <= box.dhp_max_km + 1e-9)
    return dha[ok], dhp[ok]


def align_nodes(
    target: Trajectory,
    observer: ObserverPlaneModel,
    windows: AccessWindows,
    box: HeightBox,
    sample_s: float = 1.0,
    max_miss_km: float = 10.0,
    tol_s: float = 1e-4,
) -> list[Candidate]:
    """Run Step B over every access moment of every pass, both nodes; return candidates ranked by miss.

    Each pass contributes its best candidate (if its miss is at most ``max_miss_km``):
    where the box can align the node line exactly during the pass, the grid point with
    the smallest change (|(dHa, dHp)|) and the moment it aligns; otherwise the corner
    of the box that comes closest and the miss it leaves. Ties in miss are broken by
    the smaller change.
    """
    if len(windows) == 0:
        return []
    corners = observer.rate_change(
        np.array([box.dha_min_km, box.dha_min_km, box.dha_max_km, box.dha_max_km]),
        np.array([box.dhp_min_km, box.dhp_max_km, box.dhp_min_km, box.dhp_max_km]),
    )
    edge_a, edge_p = box.dha_km, box.dhp_km
    edges = np.concatenate(
        [
            observer.rate_change(edge_a, box.dhp_min_km),
            observer.rate_change(edge_a, box.dhp_max_km),
            observer.rate_change(box.dha_min_km, edge_p),
            observer.rate_change(box.dha_max_km, edge_p),
            corners,
        ]
    )
    q_min, q_max = float(edges.min()), float(edges.max())

    # Access moments of every pass on one array.
    counts = np.maximum(2, np.ceil((windows.set_s - windows.rise_s) / sample_s).astype(int) + 1)
    pass_of = np.repeat(np.arange(len(windows)), counts)
    frac = np.concatenate([np.linspace(0.0, 1.0, c) for c in counts])
    t = windows.rise_s[pass_of] + frac * (windows.set_s - windows.rise_s)[pass_of]
    r_t, v_t = target.state(t)
    u = r_t / np.linalg.norm(r_t, axis=0)
    n_b = observer.normal(t)
    dt = t - observer.t_ref_s
    safe_dt = np.where(np.abs(dt) > 1.0, dt, np.copysign(1.0, dt) + (dt == 0))
    # The extra nodal turn is about the pole: solve for it in a frame whose z is the pole.
    rot = np.eye(3) if observer.pole is None else pole_frame(observer.pole)
    turns = _required_turns(rot @ u, rot @ n_b)

    best: dict[int, Candidate] = {}
    bounds = np.concatenate([[0], np.cumsum(counts)])
    for branch in turns:
        q_req = branch / safe_dt
        for p in range(len(windows)):
            sl = slice(bounds[p], bounds[p + 1])
            q_pass = q_req[sl]
            jumps = np.abs(np.diff(branch[sl])) > np.pi  # the branch wrapped: no continuous solution
            if jumps.any():
                continue
            lo, hi = float(q_pass.min()), float(q_pass.max())
            cand = None
            if hi >= q_min and lo <= q_max:
                q_star = float(np.clip(0.0, max(lo, q_min), min(hi, q_max)))
                dha, dhp = _min_change_for_rate(observer, box, q_star)
                q_d = float(observer.rate_change(dha, dhp))
                if not lo <= q_d <= hi:  # snapping left the pass: step back inside
                    dha, dhp = _min_change_for_rate(observer, box, float(np.clip(q_d, lo, hi)))
                    q_d = float(np.clip(observer.rate_change(dha, dhp), lo, hi))
                cand = _exact_candidate(target, observer, box, p, t[sl], q_pass, q_d, dha, dhp, tol_s)
                reach = (q_pass >= q_min) & (q_pass <= q_max)
                t_range = (float(t[sl][reach].min()), float(t[sl][reach].max())) if reach.any() else None
                cand = replace(cand, t_access_range_s=t_range)
            else:
                q_ext = q_max if lo > q_max else q_min
                k = int(np.argmin(np.abs(edges - q_ext)))
                dha, dhp = _edge_point(box, k, edge_a.size, edge_p.size)
                n_o = observer.normal(t[sl], q_ext)
                miss, sign = node_miss_km(r_t[:, sl], v_t[:, sl], n_o)
                j = int(np.argmin(miss))
                fam_a, fam_p = height_family(observer, box, q_ext)
                cand = Candidate(
                    pass_index=p,
                    node="+OC" if sign[j] > 0 else "-OC",
                    t_access_s=float(t[sl][j]),
                    delta_ha_km=dha,
                    delta_hp_km=dhp,
                    miss_km=float(miss[j]),
                    rate_change_rad_s=q_ext,
                    t_access_range_s=None,
                    family_dha_km=fam_a,
                    family_dhp_km=fam_p,
                )
            if cand.miss_km > max_miss_km:
                continue
            old = best.get(p)
            if old is None or (round(cand.miss_km, 3), cand.change_km) < (round(old.miss_km, 3), old.change_km):
                best[p] = cand
    return sorted(best.values(), key=lambda c: (round(c.miss_km, 3), c.change_km, c.t_access_s))


def _edge_point(box: HeightBox, k: int, na: int, np_: int) -> tuple[float, float]:
    """Return the (dHa, dHp) of entry ``k`` of the concatenated edge array built in align_nodes."""
    a, p = box.dha_km, box.dhp_km
    if k < na:
        return float(a[k]), box.dhp_min_km
    k -= na
    if k < na:
        return float(a[k]), box.dhp_max_km
    k -= na
    if k < np_:
        return box.dha_min_km, float(p[k])
    k -= np_
    if k < np_:
        return box.dha_max_km, float(p[k])
    k -= np_
    return [
        (box.dha_min_km, box.dhp_min_km),
        (box.dha_min_km, box.dhp_max_km),
        (box.dha_max_km, box.dhp_min_km),
        (box.dha_max_km, box.dhp_max_km),
    ][k]


def plane_crossing_function(target: Trajectory, observer: ObserverPlaneModel, q: float):  # type: ignore[no-untyped-def]
    """Return ``g(t_s)``: the target's unit position dotted with the changed observer normal (0 on the plane)."""

    def g(t_s: Vec) -> Vec:
        r, _ = target.state(t_s)
        return (observer.normal(t_s, q) * r).sum(axis=0) / np.linalg.norm(r, axis=0)

    return g


def _exact_candidate(
    target: Trajectory,
    observer: ObserverPlaneModel,
    box: HeightBox,
    p: int,
    t_pass: Vec,
    q_pass: Vec,
    q_d: float,
    dha: float,
    dhp: float,
    tol_s: float,
) -> Candidate:
    """Find the moment in the pass where the node line meets the target for rate change ``q_d``."""
    g = plane_crossing_function(target, observer, q_d)
    values = g(t_pass)
    change = np.flatnonzero(np.sign(values[1:]) != np.sign(values[:-1]))
    if change.size:
        j = int(change[np.argmin(np.abs(q_pass[change] - q_d))])
        t_root = float(bisect_roots(g, t_pass[j : j + 1], t_pass[j + 1 : j + 2], tol_s)[0])
    else:
        t_root = float(t_pass[int(np.argmin(np.abs(values)))])
    r, v = target.state(t_root)
    miss, sign = node_miss_km(r, v, observer.normal(np.array([t_root]), q_d))
    fam_a, fam_p = height_family(observer, box, q_d)
    return Candidate(
        pass_index=p,
        node="+OC" if sign[0] > 0 else "-OC",
        t_access_s=t_root,
        delta_ha_km=dha,
        delta_hp_km=dhp,
        miss_km=float(miss[0]),
        rate_change_rad_s=q_d,
        t_access_range_s=None,
        family_dha_km=fam_a,
        family_dhp_km=fam_p,
    )


def brute_force_miss(target: Trajectory, observer: ObserverPlaneModel, t_s: Vec, dha_km: Vec, dhp_km: Vec) -> Vec:
    """Return the miss (km) at every access moment and every grid point, shape (T, A, P).

    The paper's search written out directly: for each moment and each (dHa, dHp) the
    changed observer's plane, the node line, and its angle to the target. Use it on
    small grids; it exists to check ``align_nodes`` and to benchmark against.
    """
    r, v = target.state(t_s)
    q = observer.rate_change(dha_km[:, None], dhp_km[None, :])
    out = np.empty((t_s.size, dha_km.size, dhp_km.size))
    for k in range(t_s.size):
        n_o = observer.normal(np.full(q.size, t_s[k]), q.ravel())
        miss, _ = node_miss_km(
            np.repeat(r[:, k : k + 1], q.size, axis=1), np.repeat(v[:, k : k + 1], q.size, axis=1), n_o
        )
        out[k] = miss.reshape(q.shape)
    return out
