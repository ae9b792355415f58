"""Build a reflectivity map from labelled frames: choose its look and objective on a held-out scene, fit, calibrate.

``build_map(model, radar, labelled, enhanced)``:

1. The frames are split by scene (``inference.labelled.scene_split``): whole scenes held out, never frames of one scene
   on both sides. At least 2 scenes are needed.
2. **The look** (the window, then an extra blur) is chosen by what it does to attitudes, not by how well it fits:
   for each candidate the map is fitted on the training scenes, and the held-out frames are refined from their labels
   turned by ``START_DEG`` in seeded random directions; the candidate with the lowest median error wins. (The map
   that fits the labelled frames best is not the one that refines best: on our own frames a 1 px blur lowered the
   held-out divergence and raised the refined error; design/measurements.md, "The reflectivity map's parameters".)
3. **The objective** (the silhouette prior's weight, then the likelihood's texture shape) is chosen the same way.
4. **Calibration**: on up to ``CALIBRATION_FRAMES`` held-out frames refined from their labels turned as above, the
   90 % bounds per Euler axis (``raw_bounds`` scaled and floored as the silhouette path's are,
   ``inference.trust.fit_bounds``), and the deviance above which a frame is "not this radar's look". A map whose
   held-out answers end no closer than three quarters of their starts' offset is recorded as not informative, and
   the service then answers on the silhouette as without it (on smooth physical optics a map refined 2 deg starts to
   2.3 deg, and answered frames whose silhouette answers were 60 deg off with trusted answers as far off).
5. The map is fitted again on every labelled frame; its record lists the choices with their figures, the divergence
   per labelled scene, and the time taken.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from inference.errors import DatasetError
from inference.labelled import LabelledFrames, scene_split
from inference.reflectivity import fitting
from inference.reflectivity.likelihood import deviance
from inference.reflectivity.model import Look, ReflectivityMap
from inference.reflectivity.refine import (
    MAX_RENDERS,
    FrameCost,
    Objective,
    raw_bounds,
    refine,
    refine_on,
    refine_pass,
    turned_by,
    window_about,
)
from inference.reflectivity.sites import sites_of
from inference.rotations import euler_difference, euler_from_matrix, geodesic_deg, rotation_matrix, so3_exp
from inference.simulation.radar import Radar
from inference.simulation.targets import TargetModel

Vec = NDArray[np.float64]
Say = Callable[[str], None]

SPACING_M = 0.1  # one site per 10 cm square of skin (a pixel is 9.4 x 11 cm)
START_DEG = 2.0  # the held-out frames' starts: their labels turned this far
SELECT_FRAMES = 20  # held-out frames refined per candidate (spread over the held-out scenes)
CALIBRATION_FRAMES = 30  # held-out frames the bounds and the deviance limit are fitted to
SELECT_ITERATIONS = 15
SELECT_RENDERS = 100
BLURS_PX = (0.0, 0.75, 1.5)
SILHOUETTE_WEIGHTS = (0.0, 3.0, 10.0, 30.0)
SHAPES: tuple[float | None, ...] = (2.0, None)
INFORMATIVE = 0.75
DEVIANCE_MARGIN = 1.25  # a frame whose deviance exceeds the held-out frames' largest by this factor is flagged
MIN_SCENES = 2
PASS_FRAMES = 10  # a pass's frames refined together, spread over it (the service's pass refinement takes as many)
PASS_STARTS = 1  # start directions per held-out scene in the pass check (2 starts on 2 PO scenes took ~130 CPU s)


@dataclass(frozen=True)
class MapCalibration:
    """What held-out labelled scenes said of the map's answers: bounds (scale, floor per Euler axis), the deviance
    limit, and the refined error they showed."""

    scale: tuple[float, float, float]
    floor_deg: tuple[float, float, float]
    deviance_max: float
    frames: int
    median_deg: float
    p90_deg: float
    # Whether the map brought the held-out frames' answers closer than their starts (median under INFORMATIVE x
    # START_DEG): a map that does not (smooth physical optics: a few flashes a frame) never answers.
    informative: bool = True
    # The same for whole held-out scenes refined together as still passes (``refine_pass``: one body turn common to
    # the scene's frames, from their labels all turned by START_DEG): each scene's median error, their median, and
    # whether that is under INFORMATIVE x START_DEG. A pass's frames add their flashes up, so a map can sharpen
    # passes where it cannot sharpen single frames; None where no held-out scene had 2 frames.
    pass_errors_deg: tuple[float, ...] = ()
    pass_median_deg: float | None = None
    pass_informative: bool | None = None


def check_frames(labelled: LabelledFrames, radar: Radar) -> None:
    """Refuse frames the map cannot be built from (DatasetError naming the field)."""
    shape = tuple(labelled.frames.shape[1:])
    if shape != (radar.n_range, radar.n_azimuth):
        raise DatasetError(
            f"the labelled frames are {shape[0]}x{shape[1]} px; the map's radar images {radar.n_range}x"
            f"{radar.n_azimuth} px of {radar.range_cell_m:.4f} x {radar.cross_range_cell_m:.4f} m: resample them to "
            "the models' cells (gsa's labelled format does, given range_cell_m and cross_range_cell_m)",
            field="frames",
        )
    scenes = sorted(set(labelled.scenes))
    if len(scenes) < MIN_SCENES:
        raise DatasetError(
            f"a map needs labelled frames from at least {MIN_SCENES} scenes (one is held out to choose and calibrate "
            f"it); these come from {len(scenes)}",
            field="frames",
        )


def _starts(truth: Vec, seed: int) -> Vec:
    """The labels turned by START_DEG in seeded random directions (observation frame)."""
    rng = np.random.default_rng(seed)
    out = []
    for a in truth:
        w = rng.normal(size=3)
        w *= np.radians(START_DEG) / np.linalg.norm(w)
        out.append(euler_from_matrix(so3_exp(w) @ rotation_matrix(*a)))
    return np.array(out)


def _refined(
    rmap: ReflectivityMap,
    frames: NDArray[np.floating],
    starts: Vec,
    objective: Objective,
    enhanced: NDArray[np.floating] | None,
    renderer: Any,
) -> Vec:
    """Each frame refined from its start, ``SELECT_RENDERS`` at most: the answers [N, 3]."""
    out = []
    for k in range(len(frames)):
        enh = None if enhanced is None else enhanced[k]
        out.append(
            refine(rmap, frames[k], {"start": starts[k]}, objective, enh, renderer, SELECT_RENDERS)[0].angles_deg
        )
    return np.array(out)


def spread(n: int, k: int) -> NDArray[np.intp]:
    return np.unique(np.linspace(0, n - 1, min(n, k)).round().astype(np.intp))


def build_map(
    model: TargetModel,
    radar: Radar,
    labelled: LabelledFrames,
    enhanced: NDArray[np.floating] | None = None,
    renderer: Any = None,
    seed: int = 0,
    say: Say | None = None,
) -> ReflectivityMap:
    """Build a map of ``model`` for ``radar`` from ``labelled`` frames (``enhanced``: their silhouettes from UNet++, for
    choosing the silhouette prior; None: no prior); see the module's text."""
    t0, cpu0 = time.perf_counter(), time.process_time()
    tell = say or (lambda _text: None)
    check_frames(labelled, radar)
    train_idx, held_idx = scene_split(labelled.scenes, 0.25, seed)
    train, held = labelled.subset(train_idx), labelled.subset(held_idx)
    pick = held_idx[spread(len(held_idx), SELECT_FRAMES)]
    sel_frames, sel_truth = labelled.frames[pick], labelled.angles_deg[pick]
    sel_enh = None if enhanced is None else np.asarray(enhanced)[pick]
    starts = _starts(sel_truth, seed)
    sites = sites_of(model, SPACING_M)
    tell(
        f"map: {len(sites)} sites on {model.name}; {len(train)} frames from {len(set(train.scenes))} scene(s) to fit, "
        f"{len(pick)} of {len(held)} held-out frames to choose by"
    )
    trials: list[dict[str, Any]] = []

    def fitted(look: Look, frames: LabelledFrames, iterations: int) -> ReflectivityMap:
        rmap = ReflectivityMap(sites, radar, look)
        fitting.fit(rmap, fitting.prepare(rmap, frames.frames, frames.angles_deg), iterations)
        return rmap

    def trial(rmap: ReflectivityMap, objective: Objective, what: str) -> float:
        answers = _refined(rmap, sel_frames, starts, objective, sel_enh, renderer)
        med = float(np.median(geodesic_deg(answers, sel_truth)))
        trials.append({"trial": what, "median_deg": round(med, 3)})
        tell(f"map: {what}: held-out median {med:.2f} deg")
        return med

    objective = Objective(silhouette_weight=0.0)
    best_look, best_err, best_map = Look(), np.inf, None
    for window in ("taylor", "hamming", "none"):
        look = Look(window=window)
        rmap = fitted(look, train, SELECT_ITERATIONS)
        err = trial(rmap, objective, f"window {window}")
        if err < best_err:
            best_look, best_err, best_map = look, err, rmap
    for blur in BLURS_PX[1:]:
        look = replace(best_look, blur_px=blur)
        rmap = fitted(look, train, SELECT_ITERATIONS)
        err = trial(rmap, objective, f"window {look.window}, blur {blur:g} px")
        if err < best_err:
            best_look, best_err, best_map = look, err, rmap
    assert best_map is not None
    weights = SILHOUETTE_WEIGHTS if enhanced is not None and renderer is not None else (0.0,)
    for w in weights[1:]:
        cand = Objective(silhouette_weight=w)
        err = trial(best_map, cand, f"silhouette weight {w:g}")
        if err < best_err:
            objective, best_err = cand, err
    for shape in SHAPES[1:]:
        cand = replace(objective, shape=shape)
        err = trial(best_map, cand, f"texture shape {shape}")
        if err < best_err:
            objective, best_err = cand, err
    cal_idx = held_idx[spread(len(held_idx), CALIBRATION_FRAMES)]
    calibration = _calibrate(
        best_map,
        labelled.frames[cal_idx],
        labelled.angles_deg[cal_idx],
        _starts(labelled.angles_deg[cal_idx], seed + 1),
        objective,
        None if enhanced is None else np.asarray(enhanced)[cal_idx],
        renderer,
    )
    calibration = _calibrate_passes(calibration, best_map, labelled, held_idx, objective, seed + 2)
    tell(
        f"map: chose {best_look}, {objective}; held-out median {calibration.median_deg:.2f} deg (frames), "
        f"{calibration.pass_median_deg} deg (passes); fitting on all "
        f"{len(labelled)} frames"
    )
    final = ReflectivityMap(sites, radar, best_look)
    prepared = fitting.prepare(final, labelled.frames, labelled.angles_deg)
    fitting.fit(final, prepared, fitting.ITERATIONS)
    div = fitting.divergence(final, prepared)
    per_scene: dict[str, float] = {}
    for name in sorted(set(labelled.scenes)):
        rows = [i for i, s in enumerate(labelled.scenes) if s == name]
        per_scene[name] = round(float(np.mean(div[rows])), 5)
    final.record = {
        "target": model.name,
        "sites": len(sites),
        "spacing_m": SPACING_M,
        "look": asdict(best_look),
        "objective": asdict(objective),
        "calibration": asdict(calibration),
        "trials": trials,
        "divergence_per_scene": per_scene,
        "frames": len(labelled),
        "scenes": len(set(labelled.scenes)),
        "list_sha256": labelled.list_sha256(),
        "seconds": round(time.perf_counter() - t0, 1),
        "cpu_seconds": round(time.process_time() - cpu0, 1),
    }
    return final


def _calibrate(
    rmap: ReflectivityMap,
    frames: NDArray[np.floating],
    truth: Vec,
    starts: Vec,
    objective: Objective,
    enhanced: NDArray[np.floating] | None,
    renderer: Any,
) -> MapCalibration:
    """Refine the held-out frames fully, and fit the bounds and the deviance limit to what they show."""
    from inference.trust import fit_bounds

    found, raws, devs = [], [], []
    for k in range(len(frames)):
        window = window_about(rmap, starts[k])
        cost = FrameCost(rmap, frames[k], window, objective, None if enhanced is None else enhanced[k], renderer)
        a = refine_on(cost, {"start": starts[k]}, MAX_RENDERS)[0].angles_deg
        found.append(a)
        raws.append(raw_bounds(cost, a))
        devs.append(deviance(rmap, cost.data, rotation_matrix(*a), window))
    answers, raw = np.array(found), np.array(raws)
    err = np.abs(euler_difference(answers, truth))
    pairs = [fit_bounds(raw[:, i], err[:, i]) for i in range(3)]
    geo = geodesic_deg(answers, truth)
    return MapCalibration(
        tuple(round(p[0], 4) for p in pairs),  # type: ignore[arg-type]
        tuple(round(p[1], 4) for p in pairs),  # type: ignore[arg-type]
        round(float(np.nanmax(devs)) * DEVIANCE_MARGIN, 4),
        len(frames),
        round(float(np.median(geo)), 3),
        round(float(np.percentile(geo, 90)), 3),
        bool(np.median(geo) < INFORMATIVE * START_DEG),
    )


def pass_rows(scenes: tuple[str, ...] | list[str], rows: NDArray[np.intp]) -> list[NDArray[np.intp]]:
    """``rows`` grouped by scene (sorted by name), each spread to at most PASS_FRAMES; scenes of one frame left out."""
    out = []
    for name in sorted({scenes[i] for i in rows}):
        mine = np.array([i for i in rows if scenes[i] == name], dtype=np.intp)
        if len(mine) >= 2:
            out.append(mine[spread(len(mine), PASS_FRAMES)])
    return out


def _calibrate_passes(
    calibration: MapCalibration,
    rmap: ReflectivityMap,
    labelled: LabelledFrames,
    held_idx: NDArray[np.intp],
    objective: Objective,
    seed: int,
) -> MapCalibration:
    """Refine each held-out scene as one still pass from its labels all turned by START_DEG (PASS_STARTS seeded body
    directions), and record how close the passes end (see ``MapCalibration``)."""
    rng = np.random.default_rng(seed)
    errors = []
    for rows in pass_rows(labelled.scenes, np.asarray(held_idx, np.intp)):
        truth, frames = labelled.angles_deg[rows], labelled.frames[rows]
        for _ in range(PASS_STARTS):
            w = rng.normal(size=3)
            starts = turned_by(truth, so3_exp(np.radians(START_DEG) * w / np.linalg.norm(w)))
            turn, _, _ = refine_pass(rmap, frames, starts, objective)
            errors.append(round(float(np.median(geodesic_deg(turned_by(starts, turn), truth))), 3))
    if not errors:
        return calibration
    med = round(float(np.median(errors)), 3)
    return replace(
        calibration,
        pass_errors_deg=tuple(errors),
        pass_median_deg=med,
        pass_informative=bool(med < INFORMATIVE * START_DEG),
    )
