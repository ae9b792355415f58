"""Checked attitudes: the fitted answer, how sure it is, what else fits, and whether to trust it.

numpy and scipy only (the service's side). ``Checker.check`` takes a normalised frame,
UNet++'s enhanced frame and Swin's answer (None for a target without networks), fits
the target's projection (``inference.fit``), and returns a ``Checked``:

* ``angles_deg``: the fitted attitude (Swin's own when ``refine`` is off);
* ``quality.silhouette_iou``: the hard IoU of the fitted projection (the label
  ``label_mask`` would draw) with the silhouette (> 0.5) it was fitted to: the enhanced frame's, or for a
  frame the library search answered, the set's search UNet++'s where it has one;
* ``quality.uncertainty_deg``: a 90 % bound per axis (z, y, x) on the error. From the fit's
  curvature: ``raw = sqrt(inv(H)_ii * (1 - soft IoU))``, the error a residual of that size
  would leave along a valley of that curvature, then ``bound = sqrt(floor^2 + (scale raw)^2)``
  with ``scale`` and ``floor`` per axis fitted on fresh frames so 90 % of the errors fall
  inside (``calibrate``). Without refinement: the calibration frames' 90 % quantile of
  Swin's own error;
* ``quality.trusted`` and ``quality.reasons``: every check the answer failed, in words;
* ``alternatives``: other attitudes (the near-mirror (z, -y, -x), library matches, the answer's tilts) whose
  fit is within ``ALTERNATIVE_MARGIN`` of the best, each with its own IoU; the other branch's best fit whatever its
  gap; and the answer's exact near-mirror itself where that fit settled over ``TWIN_SAME_DEG`` from it.

The checks, each a threshold from the calibration (``trust.json`` beside the models):
the frame's brightness statistics lie where fresh frames' do (the median pixel; catches
frames normalised twice, inverted frames, noise); UNet++ is sure of its pixels (the share
of enhanced pixels between 0.1 and 0.9, against the silhouette's area); the projection
fits (``iou_min``); the fit stayed near Swin's answer (``moved_max_deg``; not for a library search's answer); the attitude
lies in the +-45 deg the networks were trained on (with a margin); no other attitude fits
within ``ambiguity_margin``; and the bound is under ``max_bound_deg``.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from inference.checked import NETWORK, SILHOUETTE, Alternative, Checked, Quality, StillRefinement
from inference.errors import Cancelled, ModelFileError
from inference.files import read_json, write_json
from inference.fit import (
    COMMON_SPACING_PX,
    Fit,
    FitOptions,
    Library,
    Renderer,
    brightness_agreement,
    curvature,
    fit,
    mirror,
    silhouette_iou,
)
from inference.rotations import euler_from_matrices, geodesic_deg, rotation_matrices, so3_exp
from inference.simulation.radar import Radar
from inference.simulation.targets import TargetModel

Vec = NDArray[np.float64]
Enhancer = Callable[[NDArray[np.float32]], NDArray[np.float32]]  # a normalised frame [H, W] -> its enhanced frame

TRUST_FILE = "trust.json"
CUBE_DEG = 45.0  # the networks' training range per Euler angle
ALTERNATIVE_MARGIN = 0.02  # soft-IoU cost within which another attitude is listed
AMBIGUOUS = "fits nearly as well: the frame cannot tell them apart"  # the end of the one reason a pass can resolve
BRIGHTNESS_MARGIN = 0.01  # silhouettes this close (soft IoU) are told apart by their bright parts
# The answer's own near-mirror (or its other branch's refit) is told apart by its bright parts from further off, where
# they agree better by a clear lead: the pair's silhouettes differ only where the target is not symmetric, so on a
# frame whose silhouette UNet++ draws poorly the wrong branch can fit a few hundredths better, and the bright parts
# (which side faces the radar) then tell the truth. On the calibration's 600 robust frames over SO(3) (seed 70002)
# no correct answer's other branch within 0.07 agreed better, and 3 of the 6 wrong-branch answers had the truth side
# within 0.02, brighter by 0.04-0.10; on a fresh draw (seed 78001) two correct answers' wrong branches, within 0.013
# and 0.050, were brighter by 0.008 and 0.019, hence the lead. An answer chosen so fits its silhouette worse than its
# other branch, which is listed with a negative gap: it is never trusted as unambiguous.
# design/measurements.md, "The bright parts choose between the branches from further off"
BRANCH_BRIGHTNESS_MARGIN = 0.05
BRANCH_BRIGHTNESS_LEAD = 0.03
DISTINCT_DEG = 5.0  # an alternative is at least this far from the answer
# From library starts: first the coarse coverage (smooth, within a degree or two), then the fine label.
LIBRARY_COARSE = FitOptions(
    steps_deg=(4.0, 2.0, 1.0),
    max_iter=(3, 3, 3),
    prior_weight=0.0,
    prune=0.05,
    prune_at_start=False,
    coarse=True,
    local=True,
)
LIBRARY_FINE = FitOptions(steps_deg=(2.0, 1.0, 0.5, 0.25, 0.12), max_iter=(4, 4, 3, 2, 2), prior_weight=0.0, local=True)
UNREFINED = FitOptions(steps_deg=(), prior_weight=0.0)  # a start's own soft IoU, not moved
# An alternative's ``start`` where it is the answer's exact near-mirror, listed unrefined (``Checker._near_mirror``).
NEAR_MIRROR = "near-mirror"
# A listed fit this close to the answer's exact near-mirror reads that branch as the twin does (about a good answer's
# 90 % bound on our frames); farther, the twin is listed beside it, so an answer read within 5 deg of the wrong branch
# lists the truth whichever way the fit on the truth's side went.
TWIN_SAME_DEG = 2.0


# A search's answer is refined again from tilts of this size out of the image plane, about the range and the
# cross-range axes: a silhouette pins the turn within the image plane, but near a pose it barely tells from its
# tilted neighbours the landscape holds several basins 10-25 deg apart, which the coarse fit merges (its pooled
# pixels) and the fine fit, started in one, never leaves. Two rounds at most: another only where one moved the
# answer into another basin. The tilts go down to 0.5 deg steps; the one that beats the answer is polished
# (design/measurements.md, "Neighbouring basins and the library's starts").
TILT_DEG = 12.0
TILT_ROUNDS = 2
TILT_FIT = FitOptions(steps_deg=(2.0, 1.0, 0.5), max_iter=(4, 4, 3), prior_weight=0.0, local=True)
TILT_POLISH = FitOptions(steps_deg=(0.25, 0.12), max_iter=(2, 2), prior_weight=0.0, local=True)

# The other branch's best fit is tilted as the answer was only where the choice is open: it fits within
# ALTERNATIVE_MARGIN of the answer, or the answer itself fits poorly (soft IoU below this; 5 % of SO(3) frames).
# Tilting it on every frame cost 40-60 % more time a frame
# (design/measurements.md, "Both branches settle where they fit best").
TILT_OTHER_BELOW = 0.8

# A network answer (or its near-mirror) whose silhouette IoU lies this far below ``search_below`` is not fitted: a
# fit from Swin's answer raised the better of the two by at most 0.17 over 600 frames over SO(3) and the robust
# preset's, so such a fit can never reach ``search_below``, and the search's answer beat every such fit. On frames
# over SO(3), 9 in 10 of Swin's in-cube answers are that far off; their two fits (on the networks' silhouette, then
# on the search's) were a quarter of a frame's fitting time
# (design/measurements.md, "A network answer that cannot fit is not fitted").
NETWORK_FIT_GAIN = 0.3

# The share of the calibration's network answers (frames inside the cube) whose fit the library search re-examines:
# the search trigger sits at their 5th percentile of IoU, less the trust threshold's 0.005. With default and robust
# frames in one calibration the trust threshold (the 1st percentile) falls among the robust frames' fits (0.943,
# where our frames' 1st percentile is 0.975), and as the trigger it let a robust frame's answer 18 deg off fit at
# 0.947, trusted and never searched. The search keeps the network's fits among its starts, so it changes an answer
# for one that fits better; it runs on about 1 in 100 of our frames in the cube
# (design/measurements.md, "The search re-examines the worst-fitting network answers").
SEARCH_SHARE = 0.05


class ImageRefinement(Protocol):
    """What refines a checked answer on the frame's image (``inference.reflectivity.serve.ImageRefiner``)."""

    def refine_checked(self, checked: Checked, frame: Vec, enhanced: Vec, renderer: Renderer) -> Checked: ...

    def refine_still(self, frames: NDArray[np.floating], angles_deg: Vec) -> StillRefinement | None: ...


def in_cube(angles_deg: Vec) -> bool:
    """Whether an attitude lies in the +-``CUBE_DEG`` the networks were trained on, every Euler angle."""
    return bool(np.max(np.abs(np.asarray(angles_deg, float))) <= CUBE_DEG)


def tilted(renderer: Renderer, angles_deg: Vec, tilt_deg: float = TILT_DEG) -> Vec:
    """The attitude [3] turned by ``tilt_deg`` either way about the image's range and cross-range axes
    (observation frame): [4, 3] Euler angles."""
    axes = renderer.rows / np.linalg.norm(renderer.rows, axis=1, keepdims=True)  # (2, 3): range, cross-range
    turns = so3_exp(np.radians(tilt_deg) * np.concatenate([axes, -axes]))
    return euler_from_matrices(turns @ rotation_matrices(np.asarray(angles_deg, float)[None])[0])


@dataclass(frozen=True)
class Calibration:
    """Thresholds and the uncertainty model; ``calibrate`` fits them on fresh frames of ``target``."""

    target: str = "tiangong-like"
    iou_min: float = 0.95
    doubt_max: float = 0.08
    median_range: tuple[float, float] = (0.1, 0.65)
    moved_max_deg: float = 5.0
    angle_limit_deg: float = 50.0
    # The network path's ambiguity margin and widest trusted 90 % bound: these defaults on our own radar; a set
    # recalibrated on another radar's frames chooses its own on them (``network_limits``).
    ambiguity_margin: float = 0.002
    max_bound_deg: float = 5.0
    scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    floor_deg: tuple[float, float, float] = (0.1, 0.2, 0.3)
    network_bound_deg: tuple[float, float, float] = (1.0, 1.5, 1.5)
    made: dict[str, Any] = field(default_factory=dict)
    # The library search's answers (a frame whose network answer did not fit, or a target without networks), where
    # the calibration had such frames (``calibrate``: frames over all of SO(3)): their own IoU threshold and bounds,
    # no +-50 deg limit. None: those answers are held to the network path's thresholds, bounds and limit (a
    # calibration made before these existed, or one with too few searched frames; ``calibrate`` then counts them in
    # the network path's figures). No search's answer meets the "moved from Swin" check: it is far from Swin's by design.
    library_iou_min: float | None = None
    library_doubt_max: float | None = None
    library_scale: tuple[float, float, float] | None = None
    library_floor_deg: tuple[float, float, float] | None = None
    # The widest 90 % bound a library answer may have and be trusted (None: max_bound_deg): outside the cube a wrong
    # attitude can fit UNet++'s poorer silhouette well, but the fit's curvature then bounds it loosely.
    library_max_bound_deg: float | None = None
    # The IoU below which a network answer sends the frame to the library search too (None: ``iou_min``).
    # ``calibrate`` sets it apart from the trust threshold, at the worst-fitting ``SEARCH_SHARE`` of the calibration's
    # network answers, so a search re-examines the frames the threshold trusts with least margin
    # (design/measurements.md, "The search re-examines the worst-fitting network answers"). A set recalibrated on
    # another radar's frames keeps its base set's trigger: that radar's poorer silhouettes lower the trust threshold,
    # and a trigger that low would stop the search that finds the answers Swin got wrong
    # (design/measurements.md, "The search trigger on another radar").
    search_iou_min: float | None = None
    # The ambiguity margin a library answer is held to (None: ``ambiguity_margin``): over SO(3) the fits reach a soft
    # IoU of 0.80-0.86 where in the cube 0.97-0.99, and another attitude fitting 0.01-0.02 worse is as much a
    # tie there as 0.002 is in the cube (design/measurements.md, "Trusted wrong answers over SO(3), on 600 frames").
    library_ambiguity_margin: float | None = None

    @staticmethod
    def load(path: str | Path) -> Calibration:
        raw = read_json(path, ModelFileError, "model")
        known = {k: v for k, v in raw.items() if k in Calibration.__dataclass_fields__}
        for k in ("median_range", "scale", "floor_deg", "network_bound_deg", "library_scale", "library_floor_deg"):
            if known.get(k) is not None:
                known[k] = tuple(known[k])
        return Calibration(**known)

    def write(self, path: str | Path) -> None:
        write_json(path, asdict(self))

    @property
    def covers_library(self) -> bool:
        """Whether the library search's answers have a calibration of their own (over every rotation)."""
        return self.library_scale is not None and self.library_floor_deg is not None

    @property
    def search_below(self) -> float:
        """The network answer's silhouette IoU below which the library is searched too."""
        return self.iou_min if self.search_iou_min is None else self.search_iou_min

    def holds_to_library(self, searched: bool, angles: Vec) -> bool:
        """Whether an answer's checks are the library search's own: a search's answer outside the networks' cube.

        Inside the cube UNet++'s silhouettes are as sharp as on its training frames, so the network path's thresholds
        hold there whatever found the answer (a frame normalised twice is then still flagged for UNet++'s doubt)."""
        return bool(searched and self.covers_library and not in_cube(angles))

    def bounds_model(self, searched: bool) -> tuple[Vec, Vec]:
        """(scale, floor) per axis for an answer of the library search (``searched``) or of the network path."""
        if searched and self.covers_library:
            return np.asarray(self.library_scale, float), np.asarray(self.library_floor_deg, float)
        return np.asarray(self.scale, float), np.asarray(self.floor_deg, float)


def frame_median(frame: Vec) -> float:
    return float(np.median(frame))


def enhancer_doubt(enhanced: Vec) -> float:
    """Return the share of enhanced pixels UNet++ is unsure of (0.1..0.9), over the silhouette's share."""
    sil = float(np.mean(enhanced > 0.5))
    return float(np.mean((enhanced > 0.1) & (enhanced < 0.9))) / max(sil, 1e-4)


def raw_covariance(hessian: Vec, soft_iou: float) -> Vec | None:
    """Return inv(H) (1 - soft IoU) (deg^2, the fit's Euler axes); None where H is not positive definite."""
    try:
        if np.all(np.linalg.eigvalsh(hessian) > 0):
            return np.asarray(np.linalg.inv(hessian) * max(1.0 - soft_iou, 1e-4))
    except np.linalg.LinAlgError:
        pass
    return None


def raw_uncertainty(cov: Vec | None) -> Vec:
    """Return sqrt(inv(H)_ii (1 - soft IoU)) per axis (deg) from ``raw_covariance``; infinite where it has none."""
    return np.full(3, np.inf) if cov is None else np.sqrt(np.maximum(np.diag(cov), 0.0))


def bounds_from(raw: Vec, scale: Vec, floor_deg: Vec) -> Vec:
    """The 90 % bounds per axis, sqrt(floor^2 + (scale raw)^2); infinite where ``raw`` is."""
    finite = np.isfinite(raw)
    return np.where(
        finite, np.sqrt(np.asarray(floor_deg) ** 2 + (np.asarray(scale) * np.where(finite, raw, 0.0)) ** 2), np.inf
    )


def bound_covariance(cov_raw: Vec, scale: Vec, floor_deg: Vec) -> Vec:
    """The 90 % bounds' covariance (deg^2): diag(floor^2) + S C S, S = diag(scale), C the raw covariance.

    Its diagonal is the per-axis bounds squared (``floor^2 + (scale raw)^2``); the off-diagonal
    keeps how the fit's Euler axes trade against each other (a tilt the silhouette barely shows
    lies along some mix of y and x), which a pass's fusion uses (``inference.fusion``).
    """
    s = np.diag(np.asarray(scale, float))
    return np.asarray(np.diag(np.asarray(floor_deg, float) ** 2) + s @ cov_raw @ s)


def on_other_branch(f: Fit, best: Fit) -> bool:
    """Whether ``f`` lies on ``best``'s other branch of the near-mirror pair: refined from its mirror, or within
    ``DISTINCT_DEG`` of it."""
    return f.start == "other-branch" or bool(geodesic_deg(f.angles_deg, mirror(best.angles_deg))[0] < DISTINCT_DEG)


class Checker:
    """The fit and the checks for one target and radar."""

    def __init__(
        self,
        model: TargetModel,
        radar: Radar | None = None,
        calibration: Calibration | None = None,
        networks: bool = True,
        threads: int = 0,
        image: ImageRefinement | None = None,
    ) -> None:
        import threading

        self.image = image  # the set's map refines each fitted answer on the image (``inference.reflectivity.serve``)
        self.model = model
        self.radar = radar or Radar()
        self.renderer = Renderer(model, self.radar)
        self.calibration = calibration or Calibration(target=model.name)
        self.networks = networks
        self.threads = threads  # frames ``check_many`` fits at once; 0: one a core
        self._library: Library | None = None
        self._library_lock = threading.Lock()
        self._common: Renderer | None = None

    @property
    def common_renderer(self) -> Renderer:
        """The denser skin a still pass's frames are fitted to together with (``fit_common``), built on first use."""
        with self._library_lock:
            if self._common is None:
                self._common = Renderer(self.model, self.radar, COMMON_SPACING_PX)
            return self._common

    @property
    def library(self) -> Library:
        with self._library_lock:
            if self._library is None:
                self._library = Library.build(self.renderer)
            return self._library

    def check_many(
        self,
        frames: NDArray[np.floating],
        enhanced: NDArray[np.floating],
        network_deg: NDArray[np.floating] | None,
        refine: bool = True,
        search: bool = True,
        progress: Callable[[int, int], None] | None = None,
        cancelled: Callable[[], bool] | None = None,
        search_enhancer: Enhancer | None = None,
    ) -> list[Checked]:
        """``check`` every frame [N, H, W], ``threads`` frames at once; the same answers as one by one.

        ``progress(done, total)`` is called as each frame's check ends (from the fitting threads, in turn).
        ``cancelled()`` is asked before each frame's check: once it says yes, no frame is started and
        ``Cancelled`` is raised (the frames being fitted finish).

        The fit's work is the compiled renderer's and numpy's, both of which let go of the GIL, so
        threads share the cores: two fit a 30-frame pass in 1.6 s where one takes 3.1-3.3, on 2 cores
        (design/measurements.md, "Fitting a pass's frames on every core").
        """
        import os
        import threading
        from concurrent.futures import ThreadPoolExecutor

        lock = threading.Lock()
        done = [0]

        def one(k: int) -> Checked:
            if cancelled is not None and cancelled():
                raise Cancelled(f"stopped before frame {k} of {len(frames)}")
            net = None if network_deg is None else network_deg[k]
            checked = self.check(frames[k], enhanced[k], net, refine, search, search_enhancer)
            if progress is not None:
                with lock:
                    done[0] += 1
                    progress(done[0], len(frames))
            return checked

        workers = min(self.threads or os.cpu_count() or 1, len(frames))
        if workers <= 1:
            return [one(k) for k in range(len(frames))]
        with ThreadPoolExecutor(workers, thread_name_prefix="gsa-fit") as pool:
            return list(pool.map(one, range(len(frames))))

    def check(
        self,
        frame: NDArray[np.floating],
        enhanced: NDArray[np.floating],
        network_deg: NDArray[np.floating] | None,
        refine: bool = True,
        search: bool = True,
        search_enhancer: Enhancer | None = None,
    ) -> Checked:
        """Fit (unless ``refine`` is off), bound, and check one frame; ``network_deg`` None means no networks.

        ``search`` off skips the library search where Swin's answer does not fit (a pass, whose
        other frames stand in for one that fails, saves its cost: design/measurements.md, "A pass
        skips the library search").

        ``search_enhancer`` (the model set's ``Estimator.search_enhancer``: normalised frame [H, W] -> enhanced
        [H, W]): the UNet++ whose silhouette a library search fits, every fit of that frame then scored on it;
        None: the frame's ``enhanced``. One trained over every rotation draws the silhouettes outside the cube
        that the networks' UNet++ blurs (design/measurements.md, "A search UNet++ over every rotation").
        """
        cal = self.calibration
        net = None if network_deg is None else np.asarray(network_deg, float)
        enh = np.asarray(enhanced, np.float64)
        features = {"median": frame_median(np.asarray(frame, np.float64)), "doubt": enhancer_doubt(enh)}
        fits = []
        raw_cov = None
        searched = net is None  # the answer came from a search over the library (a path calibrated on its own)
        scale, floor = cal.bounds_model(searched)
        if refine or net is None:
            # Swin's answer and its near-mirror, fitted where a fit could bring either to ``search_below``.
            hopeless = (
                net is not None
                and search
                and float(np.max(silhouette_iou(self.renderer, np.stack([net, mirror(net)]), enh)))
                < cal.search_below - NETWORK_FIT_GAIN
            )
            if net is not None and not hopeless:
                # The prior sits on Swin's answer for both: Swin saw the brightness, which tells the
                # near-mirror apart where the silhouettes are alike, so the mirror must fit clearly better.
                # The mirror is refined whatever its prior (``keep``): both branches reach the answer's alternatives
                # and the brightness tie-break.
                fits = fit(self.renderer, enh, {"network": net, "mirror": mirror(net)}, prior_at=net, keep=("mirror",))
            if net is None or hopeless or (search and self._hard_iou(fits[0].angles_deg, enh) < cal.search_below):
                # No networks, or their answer does not fit: search the library too, on the search's own
                # silhouette where there is one (the network's starts fitted again on it, so every fit is
                # scored on the one silhouette).
                networks_enh, networks_fits = enh, fits
                if search_enhancer is not None:
                    enh = np.asarray(search_enhancer(np.asarray(frame, np.float32)), np.float64)
                    features["doubt"] = enhancer_doubt(enh)
                    if net is not None and not hopeless:  # Swin's fits, fitted again on the search's silhouette
                        starts = {"network": net, "mirror": mirror(net)}
                        fits = fit(self.renderer, enh, starts, prior_at=net, keep=("mirror",))
                fits = self._searched(enh, fits)
                if enh is not networks_enh and in_cube(fits[0].angles_deg):
                    # Inside the cube the networks' UNet++ draws the sharper silhouette: it was trained there, and
                    # the search's UNet++ is the poorer one only there, at the noise floor
                    # (design/measurements.md, "The search UNet++ inside the cube"). Search again on its silhouette.
                    enh = networks_enh
                    features["doubt"] = enhancer_doubt(enh)
                    fits = self._searched(enh, networks_fits)
                searched = True
                scale, floor = cal.bounds_model(searched)
            first = fits[0]
            fits = self._by_brightness(frame, enh, self._with_other_branch(enh, fits, searched))
            if fits[0] is not first:
                # The other branch's refit fits better, or the bright parts chose another fit: its own other branch
                # may never have been refined, so refine it and choose again. (Where the best is still ``first``,
                # its other branch was refined, even if the refit moved over DISTINCT_DEG from the exact mirror:
                # refining the same start again gave the same fit twice: on 81 of 200 frames over SO(3).)
                # Its tilts too, unless that other branch is ``first``, whose neighbours the search's tilts refined.
                again = searched and geodesic_deg(mirror(fits[0].angles_deg), first.angles_deg)[0] >= DISTINCT_DEG
                refit = self._with_other_branch(enh, fits, again)
                if refit is not fits:
                    fits = self._by_brightness(frame, enh, refit)
            best = fits[0]
            angles = best.angles_deg
            hessian, soft, iou = curvature(self.renderer, enh, angles)
            raw_cov = raw_covariance(hessian, soft)
            raw = raw_uncertainty(raw_cov)
            bound = bounds_from(raw, scale, floor)
            features.update({f"raw_{a}": float(r) for a, r in zip("zyx", raw, strict=True)})
            features["soft_iou"] = soft
        else:
            angles = net
            bound = np.asarray(cal.network_bound_deg, float)
            iou = self._hard_iou(angles, enh)
        features["iou"] = iou
        features["searched"] = float(searched)
        alternatives: list[Alternative] = []
        if fits:
            for f in fits[1:]:
                dist = float(geodesic_deg(f.angles_deg, angles)[0])
                gap = fits[0].iou - f.iou  # the fits alone, without the prior
                # The other branch of the near-mirror pair is always listed (with how much worse it fits): it is the
                # ambiguity ISAR cannot rule out from a silhouette, and a pass resolves it across frames. Swin's
                # answer and its mirror are each other's other branch only where one of them is the answer: beside
                # a search's answer, Swin's mirror was listed on frames over SO(3) at soft IoU 0.25-0.77 behind it.
                other_branch = on_other_branch(f, fits[0]) or (
                    not searched and {f.start, fits[0].start} == {"network", "mirror"}
                )
                if (
                    dist >= DISTINCT_DEG
                    and (gap <= ALTERNATIVE_MARGIN or other_branch)
                    and all(geodesic_deg(f.angles_deg, np.array(a.angles_deg))[0] >= DISTINCT_DEG for a in alternatives)
                ):
                    alternatives.append(
                        Alternative(
                            tuple(float(x) for x in f.angles_deg),  # type: ignore[arg-type]
                            self._hard_iou(f.angles_deg, enh),
                            float(gap),
                            dist,
                            f.start,
                        )
                    )
            twin = self._near_mirror(enh, fits[0], angles, alternatives)
            if twin is not None:
                alternatives.append(twin)
        if net is not None:
            features["moved_deg"] = float(geodesic_deg(angles, net)[0])
        reasons = self._reasons(features, angles, bound, alternatives, net is not None and refine, searched)
        quality = Quality(round(iou, 4), tuple(round(float(b), 3) for b in bound), not reasons, reasons)  # type: ignore[arg-type]
        cov = None
        if raw_cov is not None and np.all(np.isfinite(bound)):
            cov = bound_covariance(raw_cov, scale, floor)
        checked = Checked(
            angles, net, bool(fits), quality, alternatives, features, cov, SILHOUETTE if fits else NETWORK
        )
        if self.image is not None and fits:
            return self.image.refine_checked(checked, np.asarray(frame, np.float64), enh, self.renderer)
        return checked

    def _near_mirror(
        self, enhanced: Vec, best: Fit, angles: Vec, alternatives: list[Alternative]
    ) -> Alternative | None:
        """The answer's exact near-mirror (z, -y, -x), unrefined (``start`` ``NEAR_MIRROR``), where no listed
        alternative lies within ``TWIN_SAME_DEG`` of it and it lies ``DISTINCT_DEG`` from the answer; else None.

        The mirror is an isometry of the rotations (conjugation by the reflection through the image plane), so the
        answer's twin lies exactly as far from the truth as the answer from the truth's twin: an answer read well on
        the wrong branch lists the truth. The fit on that branch, refined from the twin, can settle elsewhere where
        the silhouette is drawn unlike our renderer's (another radar's look pulls both branches, and the truth side
        need not hold a minimum near the truth): on harsh scattering it settled 6-9 deg from the truth where the
        answer lay 2-5 deg from the truth's twin. Listed with its own fit, and not judged by the ambiguity margin,
        which was calibrated on the fitted alternatives: a fit on that branch beside it fitted better on 145 of 150
        harsh frames, and where it did not, the answer was flagged already
        (design/measurements.md, "The answer's exact near-mirror listed")."""
        twin = mirror(angles)
        dist = float(geodesic_deg(twin, angles)[0])
        if dist < DISTINCT_DEG or any(
            geodesic_deg(twin, np.array(a.angles_deg))[0] < TWIN_SAME_DEG for a in alternatives
        ):
            return None
        soft = fit(self.renderer, enhanced, {NEAR_MIRROR: twin}, UNREFINED)[0].iou
        return Alternative(
            tuple(float(x) for x in twin),  # type: ignore[arg-type]
            self._hard_iou(twin, enhanced),
            float(best.iou - soft),
            dist,
            NEAR_MIRROR,
        )

    def _searched(self, enhanced: Vec, fits: list[Fit]) -> list[Fit]:
        """``fits`` and the library search's on ``enhanced``, the best one then refined from its tilts, best first."""
        return self._tilts(enhanced, sorted(fits + self.search(enhanced), key=lambda f: f.cost))

    def _tilts(self, enhanced: Vec, fits: list[Fit]) -> list[Fit]:
        """``fits`` with the best one's ``tilted`` neighbours refined (``TILT_FIT``, the one that beats it polished
        with ``TILT_POLISH``), best first; again from the new best where it lies in another basin (``DISTINCT_DEG``
        away), ``TILT_ROUNDS`` rounds at most."""
        best = fits[0]
        for _ in range(TILT_ROUNDS):
            starts = {f"tilt-{i}": a for i, a in enumerate(tilted(self.renderer, best.angles_deg))}
            tilts = fit(self.renderer, enhanced, starts, TILT_FIT)
            if tilts and tilts[0].cost < best.cost:
                polished = fit(self.renderer, enhanced, {tilts[0].start: tilts[0].angles_deg}, TILT_POLISH)
                tilts = sorted(polished + tilts[1:], key=lambda f: f.cost)
            fits = sorted(fits + tilts, key=lambda f: f.cost)
            # Another round only from another basin: a tilt that came back to the answer's own basin and settled a
            # little lower in it found nothing new.
            moved = float(geodesic_deg(fits[0].angles_deg, best.angles_deg)[0])
            best = fits[0]
            if moved < DISTINCT_DEG:
                break
        return fits

    def _with_other_branch(self, enhanced: Vec, fits: list[Fit], tilt: bool = False) -> list[Fit]:
        """The best fit's near-mirror, refined from there where no fit already lies near it (else ``fits`` itself,
        unchanged): both branches of the pair reach the brightness tie-break and the alternatives (an answer found
        by the library search, or a network answer whose own mirror start went elsewhere, had none).

        Refined as the library's starts are (coarse, then fine, in steps about the start): an answer off its own
        branch by a few degrees has a mirror as far off the other one, and outside the cube Euler steps stall near
        y = +-90 deg (design/measurements.md, "The other branch's refit"). The exact mirror is refined fine as well:
        where the answer sits on its own branch, the coarse fit's pooled pixels can drag its mirror out of the truth's
        basin into a neighbour. ``tilt`` (a searched answer), where the choice is open (the other branch within
        ``ALTERNATIVE_MARGIN`` of the answer, or the answer below ``TILT_OTHER_BELOW``): the other branch's best fit,
        new or already there, is refined again from its ``tilted`` neighbours as the answer was (``_tilts``), so that
        branch too settles in the basin that fits best
        (design/measurements.md, "Both branches settle where they fit best")."""
        other = mirror(fits[0].angles_deg)
        near = [f for f in fits if geodesic_deg(f.angles_deg, other)[0] < DISTINCT_DEG]
        refined: list[Fit] = []
        if not near:
            coarse = fit(self.renderer, enhanced, {"other-branch": other}, LIBRARY_COARSE)
            starts = {"other-branch": coarse[0].angles_deg, "other-branch-exact": other}
            refined = [replace(f, start="other-branch") for f in fit(self.renderer, enhanced, starts, LIBRARY_FINE)]
        base = near[:1] or refined[:1]
        if tilt and (fits[0].iou < TILT_OTHER_BELOW or fits[0].iou - base[0].iou <= ALTERNATIVE_MARGIN):
            refined += [f for f in self._tilts(enhanced, base) if f is not base[0]]
        if not refined:
            return fits
        return sorted(fits + refined, key=lambda f: f.cost)

    def _by_brightness(self, frame: NDArray[np.floating], enhanced: Vec, fits: list[Fit]) -> list[Fit]:
        """Where a distinct attitude's silhouette fits within ``BRIGHTNESS_MARGIN``, let the bright parts choose; the
        best fit's other branch (its near-mirror, or its refit) within ``BRANCH_BRIGHTNESS_MARGIN`` too, where its
        bright parts agree better by ``BRANCH_BRIGHTNESS_LEAD``."""
        best = fits[0]
        near = [
            f
            for f in fits[1:]
            if geodesic_deg(f.angles_deg, best.angles_deg)[0] >= DISTINCT_DEG
            and (
                best.iou - f.iou < BRIGHTNESS_MARGIN
                or (best.iou - f.iou < BRANCH_BRIGHTNESS_MARGIN and on_other_branch(f, best))
            )
        ]
        if not near:
            return fits
        mask = enhanced > 0.5
        score = {
            id(f): brightness_agreement(self.renderer, np.asarray(frame, float), f.angles_deg, mask)
            for f in [best, *near]
        }
        lead = {id(f): 0.0 if best.iou - f.iou < BRIGHTNESS_MARGIN else BRANCH_BRIGHTNESS_LEAD for f in near}
        rivals = [f for f in near if score[id(f)] > score[id(best)] + lead[id(f)]]
        winner = max([best, *rivals], key=lambda f: score[id(f)])
        return [winner, *[f for f in fits if f is not winner]]

    def search(self, enhanced: Vec, count: int = 6) -> list[Fit]:
        """Fit from the library's best ``count`` matches, coarse then fine (no network needed); best first.

        Six, not four: a library entry's match is scored where it lies, up to about half a spacing from its basin,
        and on a frame the service answered 179 deg off (trusted) the entries that lead to the truth ranked fifth and
        sixth; their coarse fits then end 0.09 ahead of the rest. The two more coarse fits cost about 5 ms a frame
        (design/measurements.md, "Neighbouring basins and the library's starts")."""
        starts = {f"library-{i}": a for i, a in enumerate(self.library.starts(enhanced, count))}
        coarse = fit(self.renderer, enhanced, starts, LIBRARY_COARSE)
        return fit(self.renderer, enhanced, {f.start: f.angles_deg for f in coarse[:3]}, LIBRARY_FINE)

    def _hard_iou(self, angles: Vec, enhanced: Vec) -> float:
        return float(silhouette_iou(self.renderer, angles, enhanced)[0])

    def _reasons(
        self,
        features: dict[str, float],
        angles: Vec,
        bound: Vec,
        alternatives: list[Alternative],
        compare_network: bool,
        searched: bool = False,
    ) -> list[str]:
        cal = self.calibration
        library = cal.holds_to_library(searched, angles)  # the search's answer, held to its own calibration
        iou_min = cal.library_iou_min if library and cal.library_iou_min is not None else cal.iou_min
        doubt_max = cal.library_doubt_max if library and cal.library_doubt_max is not None else cal.doubt_max
        max_bound = (
            cal.library_max_bound_deg if library and cal.library_max_bound_deg is not None else cal.max_bound_deg
        )
        out = []
        lo, hi = cal.median_range
        if not lo <= features["median"] <= hi:
            out.append(
                f"the frame's median brightness {features['median']:.2f} is outside the {lo:.2f}-{hi:.2f} of fresh "
                "frames: normalised twice, inverted, or not an ISAR magnitude frame?"
            )
        if features["doubt"] > doubt_max:
            out.append(
                f"UNet++ is unsure of {100 * features['doubt']:.0f} % of the silhouette's area (fresh frames: under "
                f"{100 * doubt_max:.0f} %): the frame is unlike its training frames"
            )
        if features["iou"] < iou_min:
            out.append(
                f"the {self.model.name} projection fits the enhanced silhouette poorly (IoU {features['iou']:.3f}, "
                f"fresh frames at least {iou_min:.3f}): another satellite, a flipped or transposed frame, or "
                "pixels of another size (send range_cell_m and cross_range_cell_m)?"
            )
        if compare_network and not searched and features.get("moved_deg", 0.0) > cal.moved_max_deg:
            out.append(
                f"the fit moved {features['moved_deg']:.1f} deg from the network's answer (fresh frames: under "
                f"{cal.moved_max_deg:.1f} deg)"
            )
        if not library and np.max(np.abs(angles)) > cal.angle_limit_deg:
            out.append(
                f"the attitude is outside the +-{cal.angle_limit_deg:.0f} deg the networks and the calibration cover"
                + (
                    ""
                    if cal.covers_library
                    else " (gsa calibrate --so3-frames calibrates the library search's answers)"
                )
            )
        margin = (
            cal.library_ambiguity_margin
            if library and cal.library_ambiguity_margin is not None
            else cal.ambiguity_margin
        )
        close = [a for a in alternatives if a.fit_gap < margin and a.start != NEAR_MIRROR]
        if close:
            a = close[0]
            out.append(
                f"another attitude {a.distance_deg:.0f} deg away (z {a.angles_deg[0]:.1f}, y {a.angles_deg[1]:.1f}, "
                f"x {a.angles_deg[2]:.1f})"
                + (f" (its silhouette {-a.fit_gap:.3f} better, its bright parts worse)" if a.fit_gap < 0 else "")
                + f" {AMBIGUOUS}"
            )
        if not np.all(np.isfinite(bound)) or np.max(bound) > max_bound:
            worst = "z y x".split()[int(np.argmax(np.where(np.isfinite(bound), bound, 1e9)))]
            out.append(f"the 90 % bound on {worst} is over {max_bound:g} deg: the silhouette barely constrains it")
        if not cal.made:
            out.append(
                "the thresholds and bounds are defaults, not calibrated for these models "
                "(gsa calibrate writes trust.json beside them)"
            )
        elif cal.target != self.model.name:
            out.append(
                f"the bounds and thresholds were calibrated on {cal.target}, not {self.model.name} "
                "(gsa calibrate makes a calibration for it)"
            )
        return out


def fit_bounds(raw: Vec, errors: Vec, coverage: float = 0.9) -> tuple[float, float]:
    """Return (scale, floor) for one axis: the bound sqrt(floor^2 + (scale raw)^2) covering ``coverage``.

    Of the pairs that cover, the one with the narrowest mean bound, the floor kept at or
    under the median error so the curvature, not a constant, carries the tail.

    "Cover" at split conformal prediction's finite-sample rank: the scale is the ceil((n + 1) coverage)-th smallest
    of the n frames' needs, not their empirical quantile, which covers a next frame with chance under ``coverage``
    by about 1/n: 85.6 / 87.3 / 88.6 % at n = 20 / 40 / 100 against 89.8 / 89.4 / 89.5 % at that rank (what is
    left is choosing the floor on the same frames), where an adapted set's held-out scenes hold some 40 frames
    (design/measurements.md, "Bounds fitted on few frames").
    """
    err = np.abs(errors)
    finite = np.isfinite(raw)
    raw = np.where(finite, raw, 1e6)
    best = (math.inf, 1.0, 0.0)
    rank = min(math.ceil((len(err) + 1) * coverage), len(err)) - 1
    for floor in np.quantile(err, np.linspace(0.0, 0.5, 11)):
        need = np.sqrt(np.maximum(err**2 - floor**2, 0.0)) / np.maximum(raw, 1e-9)
        scale = float(np.sort(need)[rank])
        width = float(np.mean(np.sqrt(floor**2 + (scale * raw) ** 2)))
        if width < best[0]:
            best = (width, scale, float(floor))
    return best[1], best[2]


def memoised(enhancer: Enhancer) -> Enhancer:
    """``enhancer`` run once per distinct frame (keyed by its bytes' digest; thread-safe): a calibration checks
    its frames three times."""
    import hashlib
    import threading

    done: dict[bytes, NDArray[np.float32]] = {}
    lock = threading.Lock()

    def run(frame: NDArray[np.float32]) -> NDArray[np.float32]:
        key = hashlib.blake2b(np.ascontiguousarray(frame, np.float32).tobytes(), digest_size=16).digest()
        with lock:
            hit = done.get(key)
        if hit is None:
            hit = enhancer(frame)
            with lock:
                done[key] = hit
        return hit

    return run


MIN_LIBRARY_FRAMES = 30  # searched answers a calibration needs before the library path gets thresholds of its own


def calibrate(
    checker: Checker,
    frames: NDArray[np.floating],
    enhanced: NDArray[np.floating],
    network_deg: NDArray[np.floating],
    truth: Vec,
    made: dict[str, Any] | None = None,
    progress: bool = False,
    search_iou_min: float | None = None,
    search_enhancer: Enhancer | None = None,
    own_limits: bool = False,
) -> tuple[Calibration, list[Checked]]:
    """Fit the thresholds and the uncertainty model on fresh good frames with known attitudes.

    Thresholds sit just outside what the good frames show (1st/99th percentiles with a
    margin), so about 1-2 % of good frames are flagged by design; the bounds are fitted per
    axis to cover 90 %. Returns the calibration and the frames' checks under it.

    Two paths, each calibrated on its own answers: the network path (Swin's answer refined) on
    the frames inside the networks' +-45 deg cube, and the library search's answers (a frame
    whose network answer does not fit the network path's IoU threshold) where at least
    ``MIN_LIBRARY_FRAMES`` frames took it, which frames with attitudes over all of SO(3) provide.
    The search's trigger is itself a threshold, so the frames are checked in turn: loose (no
    search: the network path's figures), with the IoU threshold set (who searches, and what the
    search finds), and under the finished calibration.

    The search's trigger sits above the IoU threshold, at the ``SEARCH_SHARE`` quantile of the network path's IoU on
    the same frames (less the same 0.005). ``search_iou_min`` fixes it instead (a set recalibrated on another radar's
    frames keeps its base set's: ``Calibration.search_iou_min``).
    ``search_enhancer``: the set's search UNet++ (``Checker.check``), run once a frame however often it is checked.
    ``own_limits``: choose the network path's bound limit and ambiguity margin on these frames too
    (``network_limits``; a set recalibrated on another radar's frames), instead of keeping the defaults.
    """
    import sys

    from inference.rotations import euler_difference

    truth = np.asarray(truth, float)
    network_deg = np.asarray(network_deg, float)
    searched_frames = None if search_enhancer is None else memoised(search_enhancer)

    def check_all(cal: Calibration, stage: str) -> list[Checked]:
        checker.calibration = cal

        def say(done: int, total: int) -> None:
            if progress and (done % 50 == 0 or done == total):
                print(f"calibrate ({stage}): {done}/{total} frames", file=sys.stderr, flush=True)

        return checker.check_many(frames, enhanced, network_deg, progress=say, search_enhancer=searched_frames)

    def features(checks: list[Checked]) -> dict[str, Vec]:
        return {key: np.array([c.features.get(key, np.nan) for c in checks]) for key in checks[0].features}

    def bounds(checks: list[Checked], rows: NDArray[np.bool_]) -> list[tuple[float, float]]:
        feats = features(checks)
        raw = np.stack([feats[f"raw_{a}"] for a in "zyx"], axis=1)[rows]
        err = euler_difference(np.array([c.angles_deg for c in checks]), truth)[rows]
        return [fit_bounds(raw[:, i], err[:, i]) for i in range(3)]

    loose = Calibration(
        target=checker.model.name,
        iou_min=0.0,
        doubt_max=math.inf,
        median_range=(0.0, 1.0),
        moved_max_deg=math.inf,
        angle_limit_deg=math.inf,
        max_bound_deg=math.inf,
    )
    first = check_all(loose, "network path")
    feats = features(first)
    cube = np.max(np.abs(truth), axis=1) <= CUBE_DEG
    net_rows = cube if cube.sum() >= MIN_LIBRARY_FRAMES else np.ones(len(frames), bool)
    first_pct, share_pct = np.quantile(feats["iou"][net_rows], [0.01, SEARCH_SHARE])
    iou_min = round(float(first_pct) - 0.005, 4)
    if search_iou_min is None:
        search_iou_min = max(iou_min, round(float(share_pct) - 0.005, 4))
    # Who searches at that threshold, and what the search finds (the library path's own figures).
    second = check_all(replace(loose, iou_min=iou_min, search_iou_min=search_iou_min), "library search")
    searched = features(second)["searched"] > 0.5
    checks = [second[k] if searched[k] else first[k] for k in range(len(frames))]
    covers = searched.sum() >= MIN_LIBRARY_FRAMES

    # Each threshold is calibrated on the answers it will judge. Without a library calibration of its own (too few
    # searched frames: a set recalibrated on another radar's frames, most of them searched) the search's answers are
    # held to the network path's doubt threshold and bounds, so they count in them; with one, only those inside the
    # cube do (``Calibration.holds_to_library``) and its bounds are the library's. The "moved from Swin" check skips
    # a search's answers, so its threshold comes from the others alone
    # (design/measurements.md, "Thresholds from the answers they judge").
    def or_all(rows: NDArray[np.bool_]) -> NDArray[np.bool_]:
        """Every frame searched (no networks' answer fitted): the network path keeps them all."""
        return rows if rows.any() else np.ones(len(frames), bool)

    outside = np.max(np.abs(np.array([c.angles_deg for c in checks])), axis=1) > CUBE_DEG
    doubt_rows = or_all(net_rows & ~(searched & outside)) if covers else net_rows
    moved_rows = or_all(net_rows & ~searched)
    bound_rows = moved_rows if covers else net_rows
    pairs = bounds(checks, bound_rows)
    library: dict[str, Any] = {}
    if covers:
        lib_pairs = bounds(checks, searched)
        lib_feats = features(second)
        library = {
            "library_doubt_max": round(float(np.quantile(lib_feats["doubt"][searched], 0.99)) * 1.25, 4),
            "library_scale": tuple(round(p[0], 4) for p in lib_pairs),
            "library_floor_deg": tuple(round(p[1], 4) for p in lib_pairs),
        }
    swin_err = np.abs(euler_difference(np.asarray(network_deg, np.float64), truth))[
        cube if cube.any() else np.ones(len(frames), bool)
    ]
    cal = Calibration(
        target=checker.model.name,
        iou_min=iou_min,
        doubt_max=round(float(np.quantile(feats["doubt"][doubt_rows], 0.99)) * 1.25, 4),
        median_range=(
            round(float(np.quantile(feats["median"], 0.005)) * 0.8, 4),
            round(float(np.quantile(feats["median"], 0.995)) + 0.05, 4),
        ),
        moved_max_deg=round(max(float(np.quantile(feats["moved_deg"][moved_rows], 0.99)) * 1.5, 3.0), 3),
        scale=tuple(round(p[0], 4) for p in pairs),  # type: ignore[arg-type]
        floor_deg=tuple(round(p[1], 4) for p in pairs),  # type: ignore[arg-type]
        network_bound_deg=tuple(round(float(q), 4) for q in np.quantile(swin_err, 0.9, axis=0)),  # type: ignore[arg-type]
        made={
            **(made or {}),
            "frames": len(frames),
            "frames_in_cube": int(cube.sum()),
            "library_frames": int(searched.sum()),
        },
        search_iou_min=search_iou_min,
        **library,
    )
    if library:
        cal = library_limits(checker, cal, checks, truth, searched)
    if own_limits:
        cal = network_limits(checker, cal, checks, truth)
    return cal, check_all(cal, "checked")


LIBRARY_BOUND_LIMITS_DEG = (1.5, 2.0, 2.5, 3.0, 4.0, 5.0)  # the library path's bound limits tried (up to max_bound_deg)
LIBRARY_AMBIGUITY_MARGINS = (0.002, 0.005, 0.01, 0.02)  # and its ambiguity margins (soft IoU)


NETWORK_BOUND_LIMITS_DEG = (5.0, 6.0, 7.0, 8.0, 10.0)  # a recalibration's network-path bound limits tried
NETWORK_AMBIGUITY_MARGINS = (0.002, 0.001, 0.0)  # and its ambiguity margins (0: flagged where a rival fits better)
NETWORK_WRONG_DEG = 5.0  # a network-path answer this far off is wrong: ``network_limits`` trusts none


def network_limits(checker: Checker, cal: Calibration, checks: list[Checked], truth: Vec) -> Calibration:
    """The network path's bound limit and ambiguity margin, for a set recalibrated on another radar's frames: of the
    limits from ``cal.max_bound_deg`` up (``NETWORK_BOUND_LIMITS_DEG``) and the margins from ``cal.ambiguity_margin``
    down (``NETWORK_AMBIGUITY_MARGINS``), the pair that trusts the most correct (<= 2 deg) calibration answers while
    trusting no answer over ``NETWORK_WRONG_DEG`` off that ``cal``'s own pair does not (every pair tried is looser,
    so it trusts all that ``cal``'s trusts); ties go to the stricter pair (the wider margin, then the tighter limit),
    so without a gain ``cal``'s own are kept. The choice and its counts go into ``made["network_limits"]``.

    The bounds are calibrated on the same frames (90 % coverage), so a bound of 6 deg on this radar is as honest as
    one of 1 deg on ours; the fixed 5 deg limit sits on another radar's typical bound and flags its good answers
    for their width alone, and there a rival within 0.002 does not tell good answers from bad
    (design/measurements.md, "Good answers flagged on another radar: the bound limit and the ambiguity margin").
    """
    err = geodesic_deg(np.array([c.angles_deg for c in checks]), truth)
    correct, wrong = err <= 2.0, err > NETWORK_WRONG_DEG
    base = trusted_under(checker, cal, checks)
    allowed = base & wrong  # the wrong answers the base pair trusts already
    chosen, chosen_trusted = cal, base
    for margin in (m for m in NETWORK_AMBIGUITY_MARGINS if m <= cal.ambiguity_margin):
        for limit in (b for b in NETWORK_BOUND_LIMITS_DEG if b >= cal.max_bound_deg):
            trial = replace(cal, max_bound_deg=limit, ambiguity_margin=margin)
            trusted = trusted_under(checker, trial, checks)
            if not (trusted & wrong & ~allowed).any() and (trusted & correct).sum() > (chosen_trusted & correct).sum():
                chosen, chosen_trusted = trial, trusted
    choice = {
        "max_bound_deg": chosen.max_bound_deg,
        "ambiguity_margin": chosen.ambiguity_margin,
        "correct_trusted": int((chosen_trusted & correct).sum()),
        "correct": int(correct.sum()),
        "wrong_trusted": int((chosen_trusted & wrong).sum()),
        "wrong": int(wrong.sum()),
        "frames": len(checks),
    }
    return replace(chosen, made={**chosen.made, "network_limits": choice})


def trusted_under(checker: Checker, cal: Calibration, checks: list[Checked]) -> NDArray[np.bool_]:
    """Whether each checked answer would be trusted under ``cal``: its checks redone from its features (no fit)."""
    kept = checker.calibration
    checker.calibration = cal
    try:
        out = []
        for c in checks:
            searched = c.features.get("searched", 0.0) > 0.5
            raw = np.array([c.features[f"raw_{a}"] for a in "zyx"])
            bound = bounds_from(raw, *cal.bounds_model(searched))
            compare = c.network_deg is not None and c.refined
            out.append(not checker._reasons(c.features, c.angles_deg, bound, c.alternatives, compare, searched))
        return np.array(out, bool)
    finally:
        checker.calibration = kept


def library_limits(
    checker: Checker, cal: Calibration, checks: list[Checked], truth: Vec, searched: NDArray[np.bool_]
) -> Calibration:
    """The library path's bound limit, ambiguity margin and IoU threshold: of ``LIBRARY_BOUND_LIMITS_DEG`` and
    ``LIBRARY_AMBIGUITY_MARGINS``, the pair whose threshold (``library_iou_threshold``: no calibration answer over
    10 deg off trusted) trusts the most correct (<= 2 deg) search answers; ties go to the smaller margin, then the
    tighter limit. A wider margin flags wrong answers that another attitude fits nearly as well (the other branch,
    most often), so the threshold need not rise above them, but it flags correct answers with a close rival too.

    Outside the cube the fit's bound tells a wrong answer from a right one better than its IoU does: on 937 searched
    calibration frames the answers 5-10 deg off that passed every check had 90 % bounds of 2.5-4.8 deg, the correct
    ones 1.5 deg at the median (2.2 at the 90th percentile), so a tighter limit lets a lower IoU threshold trust more
    correct answers with fewer wrong ones (design/measurements.md, "The library path's bound limit").
    """

    correct = searched & (geodesic_deg(np.array([c.angles_deg for c in checks]), truth) <= 2.0)
    best: tuple[int, Calibration] | None = None
    for margin in (m for m in LIBRARY_AMBIGUITY_MARGINS if m >= cal.ambiguity_margin):
        for limit in (b for b in LIBRARY_BOUND_LIMITS_DEG if b <= cal.max_bound_deg):
            trial = replace(cal, library_max_bound_deg=limit, library_ambiguity_margin=margin)
            trial = replace(trial, library_iou_min=library_iou_threshold(checker, trial, checks, truth, searched))
            kept = int((trusted_under(checker, trial, checks) & correct).sum())
            if best is None or kept > best[0]:
                best = (kept, trial)
    return (
        best[1] if best else replace(cal, library_iou_min=library_iou_threshold(checker, cal, checks, truth, searched))
    )


def library_iou_threshold(
    checker: Checker, cal: Calibration, checks: list[Checked], truth: Vec, searched: NDArray[np.bool_]
) -> float:
    """The library search's IoU threshold: under the 1st percentile of its correct answers (within 2 deg) outside the
    cube (``Calibration.holds_to_library``), and above every such answer over 10 deg off that no other check flags
    (none of the calibration's wrong answers is trusted).

    Outside the networks' cube UNet++'s silhouettes are poorer (the IoU of a correct answer there is a median 0.86
    against 0.98 inside), so a wrong attitude can fit them as well as the truth; what tells the two apart on these
    frames is how well the projection fits at all. The calibration frames' truth is known, so the threshold is set
    where their wrong answers stop being trusted, and ``bench.so3`` measures it on frames of another seed.
    """

    answers = np.array([c.angles_deg for c in checks])
    err = geodesic_deg(answers, truth)
    iou = np.array([c.features["iou"] for c in checks])
    held = searched & np.array([cal.holds_to_library(True, a) for a in answers], bool)  # the rest: network thresholds
    if not held.any():
        held = searched
    correct = held & (err <= 2.0)
    base = iou[correct] if correct.sum() >= MIN_LIBRARY_FRAMES else iou[held]
    threshold = float(np.quantile(base, 0.01)) - 0.005
    wrong = np.flatnonzero(held & (err > 10.0))
    passes = trusted_under(checker, replace(cal, library_iou_min=0.0), [checks[k] for k in wrong])
    for k in wrong[passes]:
        threshold = max(threshold, float(iou[k]) + 0.001)
    return round(threshold, 4)


class Checkers:
    """The service's targets, each with its lazily built ``Checker``; thread-safe.

    The built-in targets (``inference.simulation.targets.BUILTIN_TARGETS``) and, with ``extra``, an
    operator's own mesh. The calibration in ``model_dir/trust.json`` belongs to the target
    it names; the networks' own target (``trained_target``) starts from Swin's answer, any
    other from the library.
    """

    def __init__(
        self,
        model_dir: str | Path,
        radar: Radar | None = None,
        trained_target: str = "tiangong-like",
        extra: TargetModel | None = None,
        threads: int = 0,
        image: ImageRefinement | None = None,
    ) -> None:
        import threading

        from inference.simulation.targets import BUILTIN_TARGETS

        self.image = image  # the set's map, for its trained target only
        self.radar = radar or Radar()
        self.trained_target = trained_target
        path = Path(model_dir) / TRUST_FILE
        self.calibration = Calibration.load(path) if path.is_file() else None
        self._factories: dict[str, Any] = dict(BUILTIN_TARGETS)
        if extra is not None:
            self._factories[extra.name] = lambda: extra
        self._built: dict[str, Checker] = {}
        self._lock = threading.Lock()
        self.default = trained_target
        self.threads = threads  # each checker's ``threads``

    @property
    def names(self) -> list[str]:
        return sorted(self._factories)

    def get(self, name: str) -> Checker:
        from inference.errors import ModelFileError
        from inference.simulation.scene import check_fits

        with self._lock:
            if name in self._built:
                return self._built[name]
            if name not in self._factories:
                raise ModelFileError(
                    f"unknown target {name!r}: this service knows {', '.join(self.names)}", field="target"
                )
            model = self._factories[name]()
            check_fits(model, self.radar)
            # Another target borrows the calibrated target's thresholds (and says so in every answer).
            cal = self.calibration
            own = name == self.trained_target
            checker = Checker(model, self.radar, cal, own, self.threads, self.image if own else None)
            self._built[name] = checker
            return checker


def add_arguments(p: Any) -> None:
    from inference.simulation.catalogue import CALIBRATION_SEED

    p.add_argument("--models", default=None, help="model directory (default: the shipped models)")
    p.add_argument("--frames", type=int, default=300, help="fresh frames to calibrate on (default 300)")
    p.add_argument("--seed", type=int, default=CALIBRATION_SEED, help=f"their seed (default {CALIBRATION_SEED})")
    p.add_argument(
        "--so3-frames",
        type=int,
        default=400,
        help="fresh frames with attitudes over all of SO(3) (seed SEED+1) that calibrate the library search's answers "
        f"(0 or at least {MIN_LIBRARY_FRAMES}; default 400; the shipped trust.json used 1000; 0: none, and answers "
        "outside the networks' cube stay flagged)",
    )
    p.add_argument(
        "--so3-robust-frames",
        type=int,
        default=0,
        help="more frames over SO(3) (seed SEED+2) of the robust scattering preset (the networks' variety), so the "
        "library path's thresholds hold on scattering unlike the default simulator's too (default 0)",
    )
    p.add_argument("--out", help="where to write the calibration (default: MODELS/trust.json)")


def run(args: Any) -> int:
    """``gsa calibrate``: simulate fresh frames, run the models and the fit, and write ``trust.json``."""
    import sys
    import time
    from datetime import UTC, datetime

    from inference.errors import DatasetError
    from inference.runtime import DEFAULT_MODEL_DIR, Estimator
    from inference.simulation.catalogue import good_frames
    from inference.simulation.targets import builtin_target

    if args.frames < 50:
        raise DatasetError(f"--frames {args.frames}: calibrating needs at least 50 frames", field="frames")
    if args.so3_robust_frames < 0:
        raise DatasetError(
            f"--so3-robust-frames {args.so3_robust_frames}: give 0 or more frames", field="so3_robust_frames"
        )
    if args.so3_frames != 0 and args.so3_frames < MIN_LIBRARY_FRAMES:
        raise DatasetError(
            f"--so3-frames {args.so3_frames}: give 0 or at least {MIN_LIBRARY_FRAMES} (the library path's thresholds "
            "come from them)",
            field="so3_frames",
        )
    model_dir = Path(args.models) if args.models else DEFAULT_MODEL_DIR
    est = Estimator.load(model_dir)
    radar, target = card_radar_and_target(model_dir, est.img_size)
    t0 = time.perf_counter()
    print(
        f"calibrate: simulating {args.frames} fresh frames (seed {args.seed}) and {args.so3_frames} over SO(3) "
        f"(seed {args.seed + 1})"
        + (f", {args.so3_robust_frames} of the robust preset (seed {args.seed + 2})" if args.so3_robust_frames else ""),
        file=sys.stderr,
        flush=True,
    )
    frames, truth, _ = good_frames(args.frames, args.seed, radar, builtin_target(target))
    if args.so3_frames:
        more, more_truth, _ = good_frames(args.so3_frames, args.seed + 1, radar, builtin_target(target), "so3")
        frames, truth = np.concatenate([frames, more]), np.concatenate([truth, more_truth])
    if args.so3_robust_frames:
        more, more_truth, _ = good_frames(
            args.so3_robust_frames, args.seed + 2, radar, builtin_target(target), "so3", "robust"
        )
        frames, truth = np.concatenate([frames, more]), np.concatenate([truth, more_truth])
    res = est.estimate(frames)
    robust = f" --so3-robust-frames {args.so3_robust_frames}" if args.so3_robust_frames else ""
    made = {
        "command": f"gsa calibrate --frames {args.frames} --seed {args.seed} --so3-frames {args.so3_frames}{robust}",
        "seed": args.seed,
        "date": datetime.now(UTC).date().isoformat(),
        "models": est.identity,
    }
    cal, checks = calibrate(
        Checker(builtin_target(target), radar),
        frames,
        res.enhanced,
        res.angles_deg,
        truth,
        made,
        progress=True,
        search_enhancer=est.search_enhancer,
    )
    out = Path(args.out) if args.out else model_dir / TRUST_FILE
    cal.write(out)
    flagged = np.mean([not c.quality.trusted for c in checks])
    print(
        f"calibration written to {out} in {time.perf_counter() - t0:.0f} s; {100 * flagged:.1f} % of its frames flagged"
    )
    return 0


def card_radar_and_target(model_dir: str | Path, img_size: int = 256) -> tuple[Radar, str]:
    """The radar and target the models' training frames were made with (their card's), for the fit to render.

    Cards exported before they recorded these (the shipped models') were trained on the
    paper's radar (Table 3) and the default target.
    """
    from inference.simulation.targets import DEFAULT_TARGET

    path = Path(model_dir) / "model_card.json"
    card = json.loads(path.read_text()) if path.is_file() else {}
    radar = Radar(**card["radar"]) if card.get("radar") else Radar(n_range=img_size, n_azimuth=img_size)
    return radar, str(card.get("target") or DEFAULT_TARGET)


def load_checkers(
    model_dir: str | Path,
    img_size: int = 256,
    target_model: str | Path | None = None,
    target_scale: float = 1.0,
    default_target: str | None = None,
    threads: int = 0,
) -> Checkers:
    """The service's targets: the built-in ones and an operator's mesh, checked now; the default one built now.

    Raises ModelFileError naming the file or the target when the mesh cannot be read, does
    not fit the frame, takes a built-in target's name, or the default target is unknown.
    ``threads``: frames each checker fits at once (``Checker.check_many``; 0: one a core).
    """
    from inference.errors import ModelFileError
    from inference.simulation.meshes import load_model
    from inference.simulation.scene import check_fits
    from inference.simulation.targets import BUILTIN_TARGETS

    radar, trained = card_radar_and_target(model_dir, img_size)
    extra = None
    if target_model is not None:
        extra = load_model(target_model, target_scale)
        if extra.name in BUILTIN_TARGETS:
            raise ModelFileError(
                f"target model {target_model}: its name {extra.name!r} is a built-in target's; rename the file",
                field="target_model",
            )
        check_fits(extra, radar)
    from inference.reflectivity.serve import load_refiner

    checkers = Checkers(model_dir, radar, trained, extra, threads, load_refiner(model_dir, radar, trained))
    name = default_target or trained
    if name not in checkers.names:
        raise ModelFileError(
            f"default target {name!r} is not one this service knows ({', '.join(checkers.names)})",
            field="default_target",
        )
    checkers.default = name
    checkers.get(name)
    return checkers
