"""What the observer's optics allow: the range they resolve at, and the stand-off that keeps a fly-by trackable.

An optical observer images the target only where three limits meet. Diffraction: a telescope of
aperture D at wavelength lambda resolves an angle of 1.22 lambda / D (the Rayleigh criterion), so
a ground sample distance g is reached only within ``R_max = g D / (1.22 lambda)``. Tracking: a
straight fly-by at relative speed v that passes at distance d turns the line of sight at most at
v / d (at the closest approach), so a pointing that follows at most ``omega`` needs ``d >= v / omega``.
Light: the target must be sunlit, seen at a Sun phase angle no larger than the largest that shows
its lit side, and the boresight must stay clear of the Sun by the baffle's exclusion angle.
The defaults (``ObserverOptics()``) and where each comes from are in the class's text.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from planner.errors import PlannerError

Vec = NDArray[np.float64]

RAYLEIGH = 1.22  # the first zero of the Airy pattern: the least resolved angle is 1.22 lambda / D


# Each field of ObserverOptics: (least, most, what the refusal says). The API's schema states the same bounds.
OPTICS_LIMITS: dict[str, tuple[float, float, str]] = {
    "aperture_m": (0.01, 10.0, "between 0.01 and 10 m"),
    "wavelength_nm": (100.0, 20000.0, "between 100 and 20000 nm (UV to thermal IR)"),
    "gsd_m": (0.001, 100.0, "between 0.001 and 100 m"),
    "max_rate_deg_s": (0.001, 180.0, "between 0.001 and 180 deg/s"),
    "sun_exclusion_deg": (0.0, 180.0, "within [0, 180) deg"),
    "max_phase_angle_deg": (0.001, 180.0, "between 0.001 and 180 deg"),
}
EXCLUSIVE_MOST = frozenset({"sun_exclusion_deg"})  # 180 deg from the Sun would leave no sky


@dataclass(frozen=True, slots=True)
class ObserverOptics:
    """The observer's telescope and pointing, as far as imaging the target goes.

    Defaults: a 0.3 m aperture (a small-satellite inspection telescope's class) at 550 nm (the
    visible band's centre, Johnson V); 0.25 m ground sample distance, enough to tell the target's
    modules and wings apart for the attitude work; 10 deg/s, the line-of-sight rate a fast gimbal
    or body slew follows; 30 deg Sun exclusion, what a baffled visible telescope needs; 90 deg the
    largest Sun phase angle (beyond it the observer sees more of the target's night side than its lit one).
    """

    aperture_m: float = 0.3
    wavelength_nm: float = 550.0
    gsd_m: float = 0.25
    max_rate_deg_s: float = 10.0
    sun_exclusion_deg: float = 30.0
    max_phase_angle_deg: float = 90.0

    def __post_init__(self) -> None:
        for name, (least, most, allowed) in OPTICS_LIMITS.items():
            value = getattr(self, name)
            inside = least <= value < most if name in EXCLUSIVE_MOST else least <= value <= most
            if not (math.isfinite(value) and inside):
                raise PlannerError(f"{name} {value} must be {allowed}", field=name)

    @property
    def max_range_km(self) -> float:
        """The farthest range at which the optics resolve ``gsd_m`` (km): ``diffraction_range_km``."""
        return diffraction_range_km(self.gsd_m, self.aperture_m, self.wavelength_nm)


def diffraction_range_km(gsd_m: float, aperture_m: float, wavelength_nm: float) -> float:
    """Return the range (km) within which an aperture resolves ``gsd_m``: g D / (1.22 lambda).

    >>> round(diffraction_range_km(0.25, 0.3, 550.0), 1)
    111.8
    """
    return gsd_m * aperture_m / (RAYLEIGH * wavelength_nm * 1e-9) / 1000.0


@dataclass(frozen=True, slots=True)
class StandoffWindow:
    """The ranges a fly-by at ``relative_speed_km_s`` can be imaged from: ``[low_km, high_km]``, empty when
    ``low_km > high_km`` (``reasons`` then names the binding limits with their numbers)."""

    low_km: float
    high_km: float
    relative_speed_km_s: float
    reasons: tuple[str, ...]

    @property
    def feasible(self) -> bool:
        return self.low_km <= self.high_km

    def choose_km(self, margin: float = 0.05) -> float:
        """The stand-off to aim at: ``margin`` beyond the tracking limit (an orbit bends the straight line a
        little), within the window; where the window is empty, its upper end (the optics' range)."""
        if not self.feasible:
            return self.high_km
        return min(self.high_km, self.low_km * (1.0 + margin))


def standoff_window(
    relative_speed_km_s: float, optics: ObserverOptics, min_separation_km: float = 1.0
) -> StandoffWindow:
    """Return the stand-offs from which a straight fly-by at ``relative_speed_km_s`` can be tracked and resolved.

    The lower end is the larger of v / omega (the tracking rate at the closest approach) and the
    least separation; the upper end is the optics' diffraction range.

    >>> w = standoff_window(13.4, ObserverOptics())
    >>> round(w.low_km, 1), round(w.high_km, 1), w.feasible
    (76.8, 111.8, True)
    >>> standoff_window(20.0, ObserverOptics()).reasons[0]
    '10 deg/s needs >= 114.6 km at 20.0 km/s; the optics resolve 0.25 m only within 111.8 km'
    """
    rate_rad_s = math.radians(optics.max_rate_deg_s)
    tracking_km = relative_speed_km_s / rate_rad_s
    low = max(tracking_km, min_separation_km)
    high = optics.max_range_km
    reasons: tuple[str, ...] = ()
    if low > high:
        if tracking_km >= min_separation_km:
            need = f"{optics.max_rate_deg_s:g} deg/s needs >= {tracking_km:.1f} km at {relative_speed_km_s:.1f} km/s"
        else:
            need = f"a separation of at least {min_separation_km:g} km"
        reasons = (f"{need}; the optics resolve {optics.gsd_m:g} m only within {high:.1f} km",)
    return StandoffWindow(low, high, relative_speed_km_s, reasons)


def sun_angle_deg(r_observer_km: Vec, r_target_km: Vec, r_sun_km: Vec) -> float:
    """Return the angle (deg) between the observer's boresight (observer to target) and the Sun, seen from the observer.

    >>> sun_angle_deg(np.zeros(3), np.array([1.0, 0.0, 0.0]), np.array([-1.5e8, 0.0, 0.0]))
    180.0
    """
    bore = np.asarray(r_target_km, float) - np.asarray(r_observer_km, float)
    sun = np.asarray(r_sun_km, float) - np.asarray(r_observer_km, float)
    cos = float(bore @ sun) / (float(np.linalg.norm(bore)) * float(np.linalg.norm(sun)))
    return math.degrees(math.acos(max(-1.0, min(1.0, cos))))
