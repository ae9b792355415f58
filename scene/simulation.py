"""A simulated pass: the frames a radar forms of the target over one access window.

The scene's target over the window, the line of sight from the station in the target's LVLH
frame (``planner.frames``), and the target held at a fixed LVLH attitude or spinning about a
body axis. The line of sight *in the body* sweeps an angle over the pass; each frame is a
sub-aperture of ``aperture_deg`` of that sweep (the paper's 5.1 deg), so its integration
time follows the real rotation rate and its cross-range cell stays lambda / (2 aperture).
Its observation frame is the simulator's (X toward the radar at mid-aperture, Y the line
of sight's rate in the body), and its attitude there is what the frame is rendered at.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from inference.rotations import euler_from_matrix, rotation_matrix, spin_rotations
from planner.frames import PassGeometry, observation_axes, swept_deg
from scene.errors import SceneError
from scene.geometry import Scene

if TYPE_CHECKING:
    from inference.simulation.radar import Radar
    from inference.simulation.scene import Scattering
    from inference.simulation.targets import TargetModel

Vec = NDArray[np.float64]


@dataclass(frozen=True)
class PassOptions:
    """How to simulate a pass (``gsa simulate --pass``); see the module's text."""

    window: int | None = None  # which of the plan's access windows (None: the one that culminates highest)
    aperture_deg: float = 5.1  # each frame's sub-aperture: the angle the line of sight sweeps in the body
    step_deg: float | None = None  # between frame centres (None: the aperture, frames side by side)
    max_frames: int = 60
    attitude_lvlh_deg: tuple[float, float, float] | None = None  # body to LVLH, z y x (None: drawn)
    max_angle_deg: float = 40.0  # a drawn attitude: the middle frame's observation-frame angles within this
    spin_deg_s: float = 0.0
    spin_axis: tuple[float, float, float] = (0.0, 0.0, 1.0)  # body axis of the spin
    snr_db: tuple[float, float] | None = (-3.0, 15.0)  # drawn per frame, or None for noise-free
    snr_reference: tuple[float, float] | None = None  # (dB, km): SNR = dB - 40 log10(range / km), the radar equation
    within_deg: float | None = None  # keep only frames whose observation-frame angles are within this (trained range)
    seed: int = 0

    def __post_init__(self) -> None:
        checks = (
            ("aperture_deg", 0.5 <= self.aperture_deg <= 30.0),
            ("step_deg", self.step_deg is None or 0.5 <= self.step_deg <= 90.0),
            ("max_frames", 2 <= self.max_frames <= 1000),
            ("max_angle_deg", 0.0 <= self.max_angle_deg <= 89.0),
            ("spin_deg_s", abs(self.spin_deg_s) <= 10.0),
            ("spin_axis", len(self.spin_axis) == 3 and float(np.linalg.norm(self.spin_axis)) > 0),
            ("within_deg", self.within_deg is None or 0.0 < self.within_deg <= 180.0),
            ("snr_db", self.snr_db is None or (-30.0 <= self.snr_db[0] <= self.snr_db[1] <= 60.0)),
            ("snr_reference", self.snr_reference is None or self.snr_reference[1] > 0),
        )
        for name, ok in checks:
            if not ok:
                raise SceneError([name], f"{name} = {getattr(self, name)!r} is out of range")


@dataclass(frozen=True)
class SimulatedFrame:
    """One frame of a simulated pass, before its image: its moment, geometry and true attitudes.

    ``attitude_deg``: body to the frame's observation frame (Euler z, y, x). ``body_to_lvlh``: the
    body's attitude in LVLH; ``observation_in_lvlh`` and ``lvlh_in_gcrs``: the observation axes in
    LVLH and the LVLH axes in GCRS (columns, as ``planner.frames`` writes frames), at the frame's moment.
    """

    observed_at: datetime
    t_s: float  # on the scene's clock (s after the window's rise)
    integration_s: float
    range_km: float
    attitude_deg: tuple[float, float, float]
    body_to_lvlh: Vec
    observation_in_lvlh: Vec
    lvlh_in_gcrs: Vec


def simulate_pass(scene: Scene, opts: PassOptions, rng: np.random.Generator) -> list[SimulatedFrame]:
    """Return each frame of a simulated pass over the scene's span (an access window): no image yet.

    ``rng`` draws the attitude where ``opts`` gives none; the frames are then rendered with the
    same generator (``render_pass``), so one seed gives one pass.
    """
    duration = scene.duration_s
    t = np.arange(0.0, duration, 0.5)
    t = np.append(t, duration) if t[-1] < duration else t
    geo = scene.geometry(t)
    axis = np.asarray(opts.spin_axis, float) / np.linalg.norm(opts.spin_axis)

    def body_attitude(a0: Vec, times: Vec) -> Vec:  # body to LVLH at ``times`` (spin about the body axis)
        return np.asarray(a0 @ spin_rotations(axis, opts.spin_deg_s, times - t_mid))

    def los_body(a0: Vec, g: PassGeometry) -> Vec:  # the line of sight in body axes, from a pass_geometry's samples
        return np.einsum("nji,jn->in", body_attitude(a0, g.t_s), g.los_lvlh)

    sweep = swept_deg(geo.los_lvlh)
    t_mid = float(np.interp(0.5 * sweep[-1], sweep, t))  # the middle of the sweep (a still target's middle frame)
    step3 = np.array([-0.5, 0.0, 0.5])
    g_mid = scene.geometry(t_mid + step3)
    if opts.attitude_lvlh_deg is not None:
        a0 = rotation_matrix(*opts.attitude_lvlh_deg)
    else:  # the middle of the pass seen at angles the networks know
        wanted = rotation_matrix(*(float(v) for v in rng.uniform(-opts.max_angle_deg, opts.max_angle_deg, 3)))
        a0 = observation_axes(g_mid.los_lvlh, g_mid.t_s)[1] @ wanted
        for _ in range(8):  # a spin turns the image plane too: settle a0 so the middle frame sees ``wanted``
            a0 = a0 @ observation_axes(los_body(a0, g_mid), g_mid.t_s)[1] @ wanted
    theta = swept_deg(los_body(a0, geo))
    half = opts.aperture_deg / 2.0
    if theta[-1] < opts.aperture_deg:
        raise SceneError(
            ["window"],
            f"the line of sight sweeps only {theta[-1]:.1f} deg of the target over this "
            f"pass, less than one {opts.aperture_deg} deg sub-aperture",
        )
    step = opts.step_deg or opts.aperture_deg
    centres = np.arange(half, theta[-1] - half + 1e-9, step)
    centres += (theta[-1] - half - centres[-1]) / 2.0  # centre the frames on the pass
    out = []
    for c in centres:
        t_c = float(np.interp(c, theta, t))
        t0, t1 = float(np.interp(c - half, theta, t)), float(np.interp(c + half, theta, t))
        g = scene.geometry(t_c + step3)
        obs_body = observation_axes(los_body(a0, g), g.t_s)[1]
        angles = euler_from_matrix(obs_body.T)  # body to observation frame
        if opts.within_deg is not None and max(abs(a) for a in angles) > opts.within_deg:
            continue
        a = body_attitude(a0, np.array([t_c]))[0]
        out.append(
            SimulatedFrame(
                observed_at=scene.epoch + timedelta(seconds=t_c),
                t_s=t_c,
                integration_s=t1 - t0,
                range_km=float(g.range_km[1]),
                attitude_deg=angles,
                body_to_lvlh=a,
                observation_in_lvlh=a @ obs_body,
                lvlh_in_gcrs=g.lvlh[1],
            )
        )
    if len(out) > opts.max_frames:  # evenly thinned
        keep = np.unique(np.linspace(0, len(out) - 1, opts.max_frames).round().astype(int))
        out = [out[k] for k in keep]
    if len(out) < 2:
        raise SceneError(
            ["within_deg"],
            f"only {len(out)} frame(s) of this pass fall within the angles asked for; "
            "widen within_deg, choose another window, or give the attitude",
        )
    return out


def render_pass(
    frames: list[SimulatedFrame],
    opts: PassOptions,
    rng: np.random.Generator,
    radar: Radar | None = None,
    model: TargetModel | None = None,
    scattering: Scattering | None = None,
) -> tuple[Vec, Vec]:
    """Render each frame at its attitude; return the normalised frames [N, H, W] and their SNRs (dB, NaN: none)."""
    from inference.simulation.catalogue import at_attitudes
    from inference.simulation.scene import DEFAULT_SCATTERING

    n = len(frames)
    if opts.snr_reference is not None:
        ref_db, ref_km = opts.snr_reference
        snrs = np.array([ref_db - 40.0 * math.log10(f.range_km / ref_km) for f in frames])
    elif opts.snr_db is not None:
        snrs = rng.uniform(opts.snr_db[0], opts.snr_db[1], n)
    else:
        snrs = np.full(n, np.nan)
    seeds = [int(s) for s in rng.integers(0, 2**62, n)]
    angles = np.array([f.attitude_deg for f in frames])
    images, _ = at_attitudes(angles, snrs, seeds, radar, model, scattering or DEFAULT_SCATTERING)
    return images.astype(np.float64), np.asarray(snrs, np.float64)
