"""Frames the service must not answer with confidence, and fresh good frames to hold them against.

Each kind is a way an operator's upload can go wrong while still looking like an ISAR
frame to the networks. ``bad_frames(kind, n, seed)`` returns the normalised frames the
models would see (what ``app.services.uploads.prepare`` makes of the upload), so the
flag rate of every kind can be measured (``bench/trust.py``, ``tests/inference/test_trust.py``):

* ``other-satellite``: frames of ``comsat_like``, a box-wing satellite, not the target;
* ``range-flipped`` / ``cross-range-flipped``: the rows / columns reversed (a sign convention). Reversed
  columns are exactly the frame of the attitude turned half about the line of sight (``RX_180 @ R``,
  ``inference.rotations.reversed_reading``), whatever the scattering: over SO(3) no single-frame check can
  flag them (the answer is that attitude, and its ``attitude_reversed`` the truth); they are flagged only
  where the checks hold answers to the networks' cube, which that attitude lies outside
  (``SINGLE_FRAME_UNFLAGGABLE``);
* ``transposed``: range and cross-range swapped;
* ``normalised-twice``: a normalised frame sent again as raw (``normalised=false``);
* ``pixels-halved``: a 512 x 512 frame of the same radar resampled to 256 in pixels, not in
  metres, so the target shrinks to half its size;
* ``pixels-zoomed``: the centre 176 x 176 of a frame resampled to 256 in pixels (the target 1.45x);
* ``pure-noise``: complex white Gaussian noise, no target;
* ``inverted``: a normalised frame's negative (1 - frame), bright sky and dark target.

Good frames are ``DatasetSpec`` frames of the default target (angles uniform in +-45 deg,
SNR uniform in -3..15 dB) from a seed no training or test set uses.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from inference.frames import normalise_frame
from inference.simulation.dataset import DatasetSpec, frame_scattering, frame_truth
from inference.simulation.radar import Imager, Radar
from inference.simulation.scene import DEFAULT_SCATTERING, Scattering, simulate
from inference.simulation.targets import TargetModel, comsat_like, tiangong_like

KINDS = (
    "other-satellite",
    "range-flipped",
    "cross-range-flipped",
    "transposed",
    "normalised-twice",
    "pixels-halved",
    "pixels-zoomed",
    "pure-noise",
    "inverted",
)
SINGLE_FRAME_UNFLAGGABLE = ("cross-range-flipped",)  # an ordinary frame of another attitude (above)
CATALOGUE_SEED = 50_000  # bad frames: a seed no training, validation or test set uses
FRESH_SEED = 60_000  # fresh good frames for the trust tests and benchmarks
CALIBRATION_SEED = 70_000  # fresh good frames the shipped trust calibration was fitted on


def simulated(
    spec: DatasetSpec,
    radar: Radar | None = None,
    model: TargetModel | None = None,
    scattering: Scattering | None = None,
) -> tuple[NDArray[np.float32], NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    """Return a spec's frames (normalised), angles, SNRs and labels, of ``model`` (default: the default target).

    ``scattering``: one for every frame; None: each frame's own, as the spec draws it for training
    (``frame_scattering``: its variety preset and physics, or the default scattering).
    """
    truths = [frame_truth(spec, i) for i in range(spec.n)]
    angles = np.array([t[0] for t in truths], float).reshape(-1, 3)
    snrs = np.array([np.nan if t[1] is None else t[1] for t in truths], float)
    seeds = [t[2] for t in truths]
    each = [frame_scattering(spec, s) for s in seeds] if scattering is None else scattering
    frames, labels = at_attitudes(angles, snrs, seeds, radar, model, each)
    return frames, angles, snrs, labels


def at_attitudes(
    angles_deg: NDArray[np.float64],
    snrs_db: NDArray[np.float64],
    seeds: list[int],
    radar: Radar | None = None,
    model: TargetModel | None = None,
    scattering: Scattering | list[Scattering] = DEFAULT_SCATTERING,
) -> tuple[NDArray[np.float32], NDArray[np.bool_]]:
    """Return frames (normalised) and labels of ``model`` at given attitudes [N, 3] (z, y, x deg), SNRs (NaN: none);
    ``scattering``: one for every frame, or a list of each frame's."""
    radar = radar or Radar()
    model = model or tiangong_like()
    imager = Imager(radar)
    n = len(angles_deg)
    each = [scattering] * n if isinstance(scattering, Scattering) else list(scattering)
    if len(each) != n:
        raise ValueError(f"{len(each)} scatterings for {n} frames: give one, or one a frame")
    frames = np.empty((n, radar.n_range, radar.n_azimuth), np.float32)
    labels = np.empty((n, radar.n_range, radar.n_azimuth), bool)
    for i in range(n):
        ang = (float(angles_deg[i][0]), float(angles_deg[i][1]), float(angles_deg[i][2]))
        snr = None if not np.isfinite(snrs_db[i]) else float(snrs_db[i])
        f = simulate(model, imager, ang, snr, int(seeds[i]), each[i])
        frames[i], labels[i] = normalise_frame(np.abs(f.image)), f.label
    return frames, labels


def good_frames(
    n: int,
    seed: int = FRESH_SEED,
    radar: Radar | None = None,
    model: TargetModel | None = None,
    attitudes: str = "cube",
    variety: str | None = None,
) -> tuple[NDArray[np.float32], NDArray[np.float64], NDArray[np.float64]]:
    """Return n fresh normalised frames of ``model`` (default: the default target), their angles and SNRs.

    ``attitudes``: "cube" (each Euler angle within +-45 deg) or "so3" (uniform over every rotation); ``variety``: a
    scattering preset each frame draws from (``DatasetSpec.variety``; None: the default scattering).
    """
    spec = DatasetSpec(n=n, seed=seed, attitudes=attitudes, variety=variety)
    frames, angles, snrs, _ = simulated(spec, radar, model)
    return frames, angles, snrs


def _zoom(mag: NDArray[Any], size: int) -> NDArray[np.float64]:
    from scipy.ndimage import zoom

    return np.asarray(zoom(mag, (size / mag.shape[0], size / mag.shape[1]), order=1))


def bad_frames_truth(kind: str, n: int, seed: int = CATALOGUE_SEED) -> NDArray[np.float64]:
    """The true attitudes (Euler z, y, x deg) of ``bad_frames(kind, n, seed)``'s frames, [n, 3]."""
    if kind not in KINDS:
        raise ValueError(f"unknown kind {kind!r}; one of {', '.join(KINDS)}")
    spec = DatasetSpec(n=n, seed=seed + KINDS.index(kind) * 1000)
    return np.array([frame_truth(spec, i)[0] for i in range(n)], float).reshape(-1, 3)


def bad_frames(kind: str, n: int, seed: int = CATALOGUE_SEED, radar: Radar | None = None) -> NDArray[np.float32]:
    """Return n normalised frames of one ``KINDS`` kind, as the models would receive them."""
    if kind not in KINDS:
        raise ValueError(f"unknown kind {kind!r}; one of {', '.join(KINDS)}")
    radar = radar or Radar()
    size = radar.n_range
    spec = DatasetSpec(n=n, seed=seed + KINDS.index(kind) * 1000)
    rng = np.random.default_rng(spec.seed)
    out = np.empty((n, radar.n_range, radar.n_azimuth), np.float32)
    model = comsat_like() if kind == "other-satellite" else tiangong_like()
    if kind == "pixels-halved":
        imager = Imager(Radar(n_range=2 * radar.n_range, n_azimuth=2 * radar.n_azimuth))
    else:
        imager = Imager(radar)
    for i in range(n):
        ang, snr, s = frame_truth(spec, i)
        if kind == "pure-noise":
            mag = np.abs(rng.standard_normal((size, size)) + 1j * rng.standard_normal((size, size)))
            out[i] = normalise_frame(mag)
            continue
        mag = np.abs(simulate(model, imager, ang, snr, s).image)
        if kind == "range-flipped":
            mag = mag[::-1]
        elif kind == "cross-range-flipped":
            mag = mag[:, ::-1]
        elif kind == "transposed":
            mag = mag.T
        elif kind == "pixels-halved":
            mag = _zoom(mag, size)
        elif kind == "pixels-zoomed":
            c, half = size // 2, 88
            mag = _zoom(mag[c - half : c + half, c - half : c + half], size)
        frame = normalise_frame(mag)
        if kind == "normalised-twice":
            frame = normalise_frame(frame)
        elif kind == "inverted":
            frame = 1.0 - frame
        out[i] = frame
    return out
