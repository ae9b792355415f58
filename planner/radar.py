"""The ground radar in the scene: can it image the target at T_access?

Three limits decide it, each a plain law:

- **Elevation.** Below ``min_elevation_deg`` (default 10) the radar images through the whole
  atmosphere and its multipath; the station's visibility mask for access stays as it is.
- **Signal.** The radar equation over the coherent integration, in energy form (a matched filter
  after pulse compression; Skolnik, *Radar Handbook*, 3rd ed., eq. 1.11 with n pulses of energy
  P_t tau):

      SNR = P_t tau n G^2 lambda^2 sigma / ((4 pi)^3 R^4 k T_s L),   n = PRF x T_int

  with sigma the target's mean cross section at the scene's aspect (the band and the aperture
  averaged). The frame the estimator reads holds ``pulses`` x ``pulses`` samples of the echo, so
  its per-sample (echo-domain) SNR is this less 10 log10(pulses^2); the estimator is trained down to
  -3 dB per sample (DESIGN.md section 5), hence the default floor -3 + 48.2 = 45.2 dB.
- **Integration.** An ISAR frame's cross-range cell lambda / (2 dtheta) needs the line of sight to
  turn through the aperture dtheta *relative to the target*. A target held in its orbital frame
  (LVLH: Earth-pointing, as stations and most LEO satellites fly) turns with that frame, so the
  rate is the line of sight's in LVLH, and the integration takes dtheta / rate. It must fit within
  the coherent time the radar can hold, and hold at least ``pulses`` pulses (PRF x T_int).

Vectors are (3, N) in GCRS; times are seconds after the plan epoch, as everywhere in the planner.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from planner.errors import StationError

Vec = NDArray[np.float64]

C_M_S = 299_792_458.0
K_BOLTZMANN = 1.380649e-23  # J/K (SI, exact)
# The rate of the line of sight is a central difference over this half-step (s): the rate changes over minutes.
RATE_STEP_S = 0.5
# Rounds that stretch the integration until its ends are the aperture apart (the swept angle settles to 0.1 %).
INTEGRATION_ROUNDS = 4

# The target's mean radar cross section (m^2) along unit lines of sight (3, N), target to radar, in its LVLH frame.
CrossSection = Callable[[Vec], Vec]


@dataclass(frozen=True, slots=True)
class Radar:
    """An imaging radar's figures; each default's source is stated.

    - ``frequency_ghz`` 15, ``bandwidth_ghz`` 1.6, ``aperture_deg`` 5.1, ``pulses`` 256: the paper's Table 3
      (the frame the estimator reads: 256 range x 256 azimuth samples over a 5.1 deg aperture).
    - ``peak_power_kw`` 13, ``pulse_width_us`` 256, ``prf_hz`` 55: the Ku-band imaging channel of FHR's TIRA
      (radartutorial.eu, "TIRA"), a tracking-and-imaging radar in that band.
    - ``gain_dbi`` 72.3: a 34 m dish (TIRA's) at 15 GHz with 60 % aperture efficiency, 0.6 (pi D / lambda)^2.
    - ``noise_temperature_k`` 450: a Ku-band receiver's system temperature looking up at 10 deg: a 3 dB noise
      figure (290 K) plus antenna and sky.
    - ``losses_db`` 5: transmit, receive, atmosphere at low elevation and processing, together.
    - ``max_integration_s`` 60: the coherent time a space ISAR holds once translational motion is compensated
      (polar-format imaging takes up the migration); a LEO pass at 1,500-2,500 km turns the line of sight 5.1 deg
      in 20-80 s. Give the site's own.
    - ``min_snr_db`` 45.2: the estimator's training floor, -3 dB per sample over 256 x 256 samples.
    """

    min_elevation_deg: float = 10.0
    frequency_ghz: float = 15.0
    bandwidth_ghz: float = 1.6
    peak_power_kw: float = 13.0
    pulse_width_us: float = 256.0
    prf_hz: float = 55.0
    gain_dbi: float = 72.3
    noise_temperature_k: float = 450.0
    losses_db: float = 5.0
    aperture_deg: float = 5.1
    pulses: int = 256
    max_integration_s: float = 60.0
    min_snr_db: float = 45.2

    @property
    def wavelength_m(self) -> float:
        return C_M_S / (self.frequency_ghz * 1e9)

    @property
    def duty_cycle(self) -> float:
        return self.pulse_width_us * 1e-6 * self.prf_hz

    @property
    def min_integration_s(self) -> float:
        """The shortest integration that holds the frame's ``pulses`` pulses at the radar's PRF, s."""
        return self.pulses / self.prf_hz


# Each figure's physical range (inclusive): (low, high, what to fix).
RADAR_LIMITS: dict[str, tuple[float, float]] = {
    "min_elevation_deg": (-5.0, 89.0),
    "frequency_ghz": (0.1, 300.0),
    "bandwidth_ghz": (0.001, 50.0),
    "peak_power_kw": (0.001, 1.0e5),
    "pulse_width_us": (0.01, 1.0e5),
    "prf_hz": (0.1, 1.0e6),
    "gain_dbi": (0.0, 100.0),
    "noise_temperature_k": (1.0, 1.0e5),
    "losses_db": (0.0, 60.0),
    "aperture_deg": (0.01, 90.0),
    "pulses": (8.0, 65536.0),
    "max_integration_s": (0.001, 3600.0),
    "min_snr_db": (-50.0, 150.0),
}


def validate_radar(radar: Radar) -> None:
    """Raise StationError naming the field (``radar.<name>``) for a figure out of its physical range."""
    for name, (lo, hi) in RADAR_LIMITS.items():
        value = float(getattr(radar, name))
        if not (math.isfinite(value) and lo <= value <= hi):
            raise StationError(f"radar.{name} {value:g} is outside [{lo:g}, {hi:g}]", field=f"radar.{name}")
    if radar.bandwidth_ghz >= 2.0 * radar.frequency_ghz:
        raise StationError(
            f"radar.bandwidth_ghz {radar.bandwidth_ghz:g} must be under twice the frequency ({radar.frequency_ghz:g} GHz)",
            field="radar.bandwidth_ghz",
        )
    if radar.duty_cycle > 1.0:
        raise StationError(
            f"radar.pulse_width_us {radar.pulse_width_us:g} at radar.prf_hz {radar.prf_hz:g} is a duty cycle of "
            f"{radar.duty_cycle:.2f}, over 1: shorten the pulse or lower the PRF",
            field="radar.pulse_width_us",
        )


def snr_db(radar: Radar, range_km: Vec, rcs_m2: Vec, integration_s: Vec) -> Vec:
    """The radar equation's SNR (dB) over a coherent integration of ``integration_s``: see the module's docstring."""
    lam = radar.wavelength_m
    energy = radar.peak_power_kw * 1e3 * radar.pulse_width_us * 1e-6 * radar.prf_hz * np.asarray(integration_s, float)
    gain = 10.0 ** (radar.gain_dbi / 10.0)
    losses = 10.0 ** (radar.losses_db / 10.0)
    r_m = np.asarray(range_km, float) * 1e3
    signal = energy * gain**2 * lam**2 * np.asarray(rcs_m2, float)
    noise = (4.0 * math.pi) ** 3 * r_m**4 * K_BOLTZMANN * radar.noise_temperature_k * losses
    with np.errstate(divide="ignore"):
        return np.asarray(10.0 * np.log10(signal / noise))


@dataclass(frozen=True, slots=True)
class RadarView:
    """What the radar sees of the target at some moments; every field has one entry a moment.

    ``rate_deg_s`` is the line of sight's turn in the target's LVLH frame at the moment, ``integration_s`` the time
    centred on it over which its ends are the aperture apart (inf where it stands still), ``snr_db`` the radar equation over that time with
    ``rcs_m2`` (NaN where no cross section was given), ``los_lvlh`` (3, N) the aspect.
    """

    elevation_deg: Vec
    range_km: Vec
    rate_deg_s: Vec
    integration_s: Vec
    rcs_m2: Vec
    snr_db: Vec
    los_lvlh: Vec


# The line of sight at seconds ``t_s``: unit vectors (3, N), target to radar, in the target's LVLH axes, and the
# slant range (N,) km (``planner.frames.pass_geometry``); and the elevation (N,) deg as the station sees it.
GeometryAt = Callable[[Vec], tuple[Vec, Vec]]
ElevationAt = Callable[[Vec], Vec]


def radar_view(
    radar: Radar,
    t_s: Vec,
    geometry_at: GeometryAt,
    elevation_at: ElevationAt,
    cross_section: CrossSection | None,
) -> RadarView:
    """The radar's view of the target at ``t_s``: elevation, range, the aspect's turn rate, integration and SNR."""
    t = np.atleast_1d(np.asarray(t_s, float))
    n = t.size
    if n == 0:
        none = np.empty(0)
        return RadarView(none, none, none, none, none, none, np.empty((3, 0)))
    los, rng = geometry_at(np.concatenate([t - RATE_STEP_S, t, t + RATE_STEP_S]))
    before, now, after = los[:, :n], los[:, n : 2 * n], los[:, 2 * n :]
    rate = _angle_deg(before, after) / (2.0 * RATE_STEP_S)
    with np.errstate(divide="ignore"):
        t_int = np.where(rate > 0.0, radar.aperture_deg / rate, np.inf)
    # The rate changes across a long integration (fastest overhead): stretch it until the line of sight's ends,
    # half of it either side of the moment, are the aperture apart.
    for _ in range(INTEGRATION_ROUNDS):
        finite = np.isfinite(t_int) & (t_int < 4.0 * radar.max_integration_s)
        if not finite.any():
            break
        half = 0.5 * t_int[finite]
        ends, _ = geometry_at(np.concatenate([t[finite] - half, t[finite] + half]))
        m = int(finite.sum())
        swept = _angle_deg(ends[:, :m], ends[:, m:])
        t_int[finite] = np.where(swept > 0.0, t_int[finite] * radar.aperture_deg / np.maximum(swept, 1e-12), np.inf)
    rcs = np.full(n, np.nan) if cross_section is None else np.asarray(cross_section(now), float)
    r_now = np.asarray(rng[n : 2 * n], float)
    snr = snr_db(radar, r_now, rcs, np.minimum(t_int, radar.max_integration_s))
    return RadarView(np.asarray(elevation_at(t), float), r_now, rate, t_int, rcs, snr, now)


def _angle_deg(a: Vec, b: Vec) -> Vec:
    """The angles (deg) between unit vectors (3, N), column by column."""
    return np.asarray(np.degrees(np.arccos(np.clip((a * b).sum(0), -1.0, 1.0))))


def radar_limits(radar: Radar, elevation_deg: float, integration_s: float, snr: float) -> list[str]:
    """Each radar limit a scene misses, in words and numbers (the SNR only where it was computed)."""
    reasons = []
    if elevation_deg < radar.min_elevation_deg:
        reasons.append(
            f"the radar sees the target at {elevation_deg:.1f} deg elevation, under its min_elevation_deg "
            f"{radar.min_elevation_deg:g} (it images through the whole atmosphere and its multipath there)"
        )
    if integration_s > radar.max_integration_s:
        reasons.append(
            f"the radar's line of sight needs {integration_s:.1f} s to sweep the {radar.aperture_deg:g} deg aperture, "
            f"over the {radar.max_integration_s:g} s it holds coherent (max_integration_s)"
        )
    elif integration_s < radar.min_integration_s:
        reasons.append(
            f"the radar's line of sight sweeps the {radar.aperture_deg:g} deg aperture in {integration_s:.2f} s, "
            f"too few pulses for the frame's {radar.pulses} at {radar.prf_hz:g} Hz (at least "
            f"{radar.min_integration_s:.2f} s): cross-range would alias"
        )
    if math.isfinite(snr) and snr < radar.min_snr_db:
        reasons.append(
            f"the radar equation gives {snr:.1f} dB over the integration, under the radar's min_snr_db "
            f"{radar.min_snr_db:g}"
        )
    return reasons
