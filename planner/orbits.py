"""The satellites a plan is about, and the one place their trajectories are chosen.

An ``Orbit`` is a name and either Table-1 elements or a TLE. ``trajectory`` picks how it
moves: SGP4 for a TLE; for elements, numerical two-body + J2 (``osculating``) or the J2
secular rates (``mean``), J2 acting about the pole of date in both. ``earth_frames``
samples the Earth's orientation over a span with the one margin every caller needs.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime
from typing import Literal

import numpy as np

from planner.ccsds import Ephemeris
from planner.elements import Elements, elements_of_state
from planner.errors import PlannerError
from planner.propagation import (
    EarthFrames,
    NumericalJ2Trajectory,
    Pole,
    SecularJ2Trajectory,
    SGP4Trajectory,
    Trajectory,
    as_utc,
    pole_of_date,
    seconds_between,
)
from planner.tle import TLE

Reading = Literal["osculating", "mean"]
FRAME_MARGIN_S = 3600.0  # Earth orientation is sampled an hour either side of a span: interpolation never extrapolates


@dataclass(frozen=True, slots=True)
class Orbit:
    """A satellite: a name and either Table-1 elements or a TLE; ``notes`` say what its input held that a plan
    does not use (an OPM's manoeuvres), and every plan and campaign of it repeats them."""

    name: str
    elements: Elements | None = None
    tle: TLE | None = None
    notes: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if (self.elements is None) == (self.tle is None):
            raise PlannerError(f"{self.name}: give exactly one of elements or tle", field="elements")

    @property
    def epoch(self) -> datetime:
        if self.elements is not None:
            return as_utc(self.elements.epoch)
        assert self.tle is not None
        return self.tle.epoch


def earth_frames(epoch: datetime, t0_s: float, t1_s: float) -> EarthFrames:
    """Return the Earth's orientation over ``[t0_s, t1_s]`` after ``epoch``, with ``FRAME_MARGIN_S`` either side."""
    return EarthFrames(epoch, t0_s - FRAME_MARGIN_S, t1_s + FRAME_MARGIN_S)


def elements_trajectory(
    elements: Elements, epoch: datetime, t0_s: float, t1_s: float, reading: Reading, pole: Pole | None = None
) -> Trajectory:
    """Return the motion of ``elements`` over ``[t0_s, t1_s]`` after ``epoch``, read as ``reading``.

    J2 acts about ``pole``; by default the pole of date fitted from the element epoch over the span.
    """
    if pole is None:
        offset = seconds_between(epoch, elements.epoch)
        pole = pole_of_date(epoch, min(t0_s, offset), max(t1_s, offset))
    if reading == "mean":
        return SecularJ2Trajectory(elements, epoch, pole)
    return NumericalJ2Trajectory.from_elements(elements, epoch, t0_s, t1_s, pole)


def trajectory(
    orbit: Orbit,
    epoch: datetime,
    frames: EarthFrames,
    t0_s: float,
    t1_s: float,
    reading: Reading,
    pole: Pole | None = None,
) -> Trajectory:
    """Return ``orbit``'s trajectory over ``[t0_s, t1_s]`` after ``epoch``: SGP4 for a TLE, else by ``reading``.

    ``frames`` (which must cover the span) turn SGP4's TEME into GCRS.
    """
    if orbit.tle is not None:
        return SGP4Trajectory(orbit.tle, epoch, frames)
    assert orbit.elements is not None
    return elements_trajectory(orbit.elements, epoch, t0_s, t1_s, reading, pole)


def osculating_elements(orbit: Orbit, epoch: datetime, frames: EarthFrames) -> Elements:
    """Return ``orbit``'s elements; for a TLE, its osculating GCRS state at ``epoch`` as elements of that epoch."""
    if orbit.elements is not None:
        return orbit.elements
    assert orbit.tle is not None
    r, v = SGP4Trajectory(orbit.tle, epoch, frames).state(0.0)
    return elements_of_state(r[:, 0], v[:, 0], epoch)


def ephemeris_note(eph: Ephemeris, name: str) -> str:
    """What an OEM read as an orbit input means for a plan: the plan flies two-body + J2 from its first state; how
    far that flight departs from the OEM's own states over its first segment (the force models' difference, which a
    plan beyond a few days inherits), and the segments not flown."""
    t0 = eph.epochs[0]
    t = np.array([seconds_between(t0, e) for e in eph.epochs])
    text = f"{name}: read from the OEM's first state ({t0:%Y-%m-%dT%H:%M:%S}Z) and flown with two-body + J2"
    if t.size > 1:
        flown = NumericalJ2Trajectory.from_elements(eph.elements, t0, 0.0, float(t[-1]))
        r, _ = flown.state(t)
        off = np.linalg.norm(r - eph.r_km, axis=0)
        worst = int(np.argmax(off))
        text += (
            f"; over the OEM's first segment ({t.size} states, {t[-1] / 86400.0:.2f} days) that flight departs from "
            f"its states by up to {off[worst]:.3f} km ({t[worst] / 3600.0:.1f} h in)"
        )
    if eph.segments > 1:
        text += (
            f"; its {eph.segments - 1} later segment(s) (after a manoeuvre, or another object) are not flown: to plan "
            "from after a burn, send the state orbit determination gives after it"
        )
    return text
