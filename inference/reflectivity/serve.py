"""The map in a model set: its file beside the networks, and the refinement of each checked answer on the image.

``save_map(rmap, model_dir)`` writes ``reflectivity.npz`` (no pickles) and returns the card's entry;
``load_refiner(model_dir, radar, target)`` reads it back when the set's card lists one (None otherwise), checking its
sha256, its radar and that the target's skin is the one it was built on.

``ImageRefiner.refine_checked`` takes the silhouette path's checked answer (``inference.trust.Checker.check``) and
refines the answer and its listed alternatives on the frame's likelihood under the map; the best one answers, with
``refined_on`` "image", its 90 % bounds from the likelihood's curvature (calibrated when the map was built), the other
refined attitudes as alternatives with their gap in the objective, and the reasons not to trust it: a rival within
``AMBIGUITY_GAP``, a bound over ``MAX_BOUND_DEG``, or a frame the map cannot explain (its deviance over the limit the
labelled frames set: "not this radar's look"). A map its build found not informative (held-out answers no closer
than their starts) leaves every answer to the silhouette path.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from inference.checked import IMAGE, Alternative, Checked, Quality, StillRefinement
from inference.errors import ModelFileError
from inference.files import checked_file, sha256_file
from inference.fit import Renderer, silhouette_iou
from inference.reflectivity.build import PASS_FRAMES, spread
from inference.reflectivity.likelihood import deviance
from inference.reflectivity.model import LAW_BINS, Look, ReflectivityMap
from inference.reflectivity.refine import (
    PASS_RENDERS,
    FrameCost,
    Objective,
    raw_bounds,
    refine_on,
    refine_pass,
    window_about,
)
from inference.reflectivity.sites import sites_of
from inference.rotations import geodesic_deg, rotation_matrix
from inference.simulation.radar import Radar
from inference.simulation.targets import TargetModel

Vec = NDArray[np.float64]

MAP_FILE = "reflectivity.npz"
MAP_ROLE = "map"
MAX_ALTERNATIVES = 3  # listed alternatives scored on the image; the best-scoring one is refined beside the answer
REFINE_RENDERS = 120
AMBIGUITY_GAP = 0.002  # objective per pixel within which another attitude is as likely
MAX_BOUND_DEG = 5.0
DISTINCT_DEG = 5.0
RESIDUAL_DB = 10.0  # the residual view's span either way
FRAME_REASONS = ("the frame's median brightness",)  # the silhouette path's reasons that concern the frame itself


def save_map(rmap: ReflectivityMap, model_dir: str | Path) -> dict[str, Any]:
    """Write the map into ``model_dir``; return its card entry (file, sha256)."""
    assert rmap.law is not None and rmap.rho is not None
    path = Path(model_dir) / MAP_FILE
    meta = {
        "target": rmap.sites.target,
        "fingerprint": rmap.sites.fingerprint,
        "spacing_m": float(rmap.record.get("spacing_m", 0.1)),
        "radar": {f: getattr(rmap.radar, f) for f in rmap.radar.__dataclass_fields__},
        "look": asdict(rmap.look),
        "record": rmap.record,
    }
    with path.open("wb") as fh:
        np.savez(fh, law=rmap.law.reshape(-1, LAW_BINS), rho=rmap.rho, meta=np.array(json.dumps(meta)))
    return {"file": MAP_FILE, "sha256": sha256_file(path)}


def read_map(path: Path, model: TargetModel, radar: Radar) -> ReflectivityMap:
    """Read a map file for ``model`` and ``radar``; ModelFileError names what does not match."""
    try:
        with np.load(path, allow_pickle=False) as z:
            law, rho, meta = np.asarray(z["law"], float), np.asarray(z["rho"], float), json.loads(str(z["meta"]))
    except (OSError, ValueError, KeyError, json.JSONDecodeError) as exc:
        raise ModelFileError(f"map file {path} cannot be read: {exc}", field="model") from None
    if meta.get("target") != model.name:
        raise ModelFileError(
            f"map file {path} was built for target {meta.get('target')!r}, not {model.name!r}", field="model"
        )
    built = Radar(**meta["radar"])
    if built != radar:
        raise ModelFileError(f"map file {path} was built for another radar ({built}) than the set's", field="model")
    sites = sites_of(model, float(meta["spacing_m"]))
    if sites.fingerprint != meta.get("fingerprint") or law.shape != (sites.n_parts, LAW_BINS):
        raise ModelFileError(
            f"map file {path} was built on a mesh of {model.name} that is not this one (its skin changed): build the "
            "map again (gsa adapt --map-only)",
            field="model",
        )
    return ReflectivityMap(sites, radar, Look(**meta["look"]), law.ravel(), rho, dict(meta.get("record") or {}))


def load_refiner(model_dir: str | Path, radar: Radar, target: str) -> ImageRefiner | None:
    """The set's image refiner where its card lists a map (checked against its sha256), else None."""
    from inference.simulation.targets import builtin_target

    d = Path(model_dir)
    card_path = d / "model_card.json"
    card = json.loads(card_path.read_text()) if card_path.is_file() else {}
    entry = (card.get("files") or {}).get(MAP_ROLE)
    if not entry:
        return None
    path = checked_file(d / entry["file"], entry["sha256"], "map file")
    return ImageRefiner(read_map(path, builtin_target(target), radar))


class ImageRefiner:
    """Refines checked answers on the image under one map (see the module's text); thread-safe (no shared state)."""

    def __init__(self, rmap: ReflectivityMap) -> None:
        self.map = rmap
        rec = rmap.record
        self.objective = Objective(**rec["objective"]) if rec.get("objective") else Objective()
        cal = rec.get("calibration") or {}
        self.scale = np.asarray(cal.get("scale", (1.0, 1.0, 1.0)), float)
        self.floor = np.asarray(cal.get("floor_deg", (1.0, 1.0, 1.0)), float)
        self.deviance_max = float(cal.get("deviance_max", math.inf))
        self.calibrated = bool(cal)
        self.informative = bool(cal.get("informative", True))
        # A map built before passes were checked: a map that sharpens single frames stands for one that sharpens passes
        passes = cal.get("pass_informative")
        self.pass_informative = self.informative if passes is None else bool(passes)

    def refine_checked(self, checked: Checked, frame: Vec, enhanced: Vec, renderer: Renderer) -> Checked:
        if not self.informative:  # the map did not sharpen held-out answers: the silhouette's stands
            return checked
        starts: dict[str, Vec] = {"answer": np.asarray(checked.angles_deg, float)}
        for i, a in enumerate(checked.alternatives[:MAX_ALTERNATIVES]):
            starts[f"{a.start}-{i}"] = np.asarray(a.angles_deg, float)
        window = window_about(self.map, starts["answer"])
        cost = FrameCost(self.map, frame, window, self.objective, enhanced, renderer)
        at_start = {name: cost(rotation_matrix(*a)) for name, a in starts.items()}
        chosen = ["answer"] + sorted((n for n in starts if n != "answer"), key=at_start.__getitem__)[:1]
        refined = refine_on(cost, {n: starts[n] for n in chosen}, REFINE_RENDERS)
        scored = [(r.angles_deg, r.cost, "image-" + r.start) for r in refined]
        scored += [(starts[n], at_start[n], n) for n in starts if n not in chosen]
        scored.sort(key=lambda t: t[1])
        best, best_cost, _ = scored[0]
        raw = raw_bounds(cost, best)
        finite = np.isfinite(raw)
        bound = np.where(finite, np.sqrt(self.floor**2 + (self.scale * np.where(finite, raw, 0.0)) ** 2), np.inf)
        dev = deviance(self.map, cost.data, rotation_matrix(*best), window)
        alternatives: list[Alternative] = []
        kept = [best]
        for angles, value, name in scored[1:]:
            if min(float(geodesic_deg(angles, k)[0]) for k in kept) < DISTINCT_DEG:
                continue
            kept.append(angles)
            alternatives.append(
                Alternative(
                    tuple(float(x) for x in angles),  # type: ignore[arg-type]
                    float(silhouette_iou(renderer, angles, enhanced)[0]),
                    float(value - best_cost),
                    float(geodesic_deg(angles, best)[0]),
                    name,
                )
            )
        reasons = [r for r in checked.quality.reasons if r.startswith(FRAME_REASONS)]
        reasons += self._reasons(bound, dev, alternatives)
        iou = float(silhouette_iou(renderer, best, enhanced)[0])
        quality = Quality(round(iou, 4), tuple(round(float(b), 3) for b in bound), not reasons, reasons)  # type: ignore[arg-type]
        fit = {"nll_per_pixel": round(best_cost, 6), "deviance": round(dev, 4), "deviance_max": self.deviance_max}
        features = {**checked.features, "image_nll": best_cost, "image_deviance": dev}
        return replace(
            checked,
            angles_deg=np.asarray(best, float),
            quality=quality,
            alternatives=alternatives,
            features=features,
            bound_cov_deg2=np.diag(bound**2) if np.all(np.isfinite(bound)) else None,
            refined_on=IMAGE,
            image_fit=fit,
        )

    def refine_still(self, frames: NDArray[np.floating], angles_deg: Vec) -> StillRefinement | None:
        """A still pass's frames refined together: ``frames`` [N, H, W], each with its attitude (Euler z, y, x deg) in its
        own observation frame, all one attitude in LVLH. One body turn common to them all is found on up to
        ``PASS_FRAMES`` frames spread over the pass (``refine_pass``); None where the map's build found that held-out
        passes were not sharpened."""
        if not self.pass_informative or len(frames) < 2:
            return None
        idx = spread(len(frames), PASS_FRAMES)
        angles = np.asarray(angles_deg, float)
        turn, best, start = refine_pass(
            self.map, np.asarray(frames)[idx].astype(np.float64), angles[idx], self.objective, PASS_RENDERS
        )
        return StillRefinement(np.asarray(turn, float), float(best), float(start), len(idx))

    def views(self, frame: Vec, angles_deg: Vec) -> tuple[Vec, Vec]:
        """What the map predicts of the whole frame at an attitude, normalised as frames are (40 dB below the
        frame's own reference, in [0, 1]), and the frame over the prediction (dB, +-``RESIDUAL_DB`` mapped to 0..1,
        0.5 where they agree); both [H, W], for the estimate's page."""
        from inference.reflectivity.likelihood import FrameData, profiled_mean
        from inference.reflectivity.model import DYNAMIC_RANGE_DB

        data = FrameData.of(frame)
        whole = (0, 0, *data.y.shape)
        mu, _ = profiled_mean(self.map, data, rotation_matrix(*np.asarray(angles_deg, float)), whole)
        predicted = np.clip(1.0 + 10.0 * np.log10(mu) / DYNAMIC_RANGE_DB, 0.0, 1.0)
        ratio_db = 10.0 * np.log10(np.maximum(data.y, 1e-12) / mu)
        return predicted, np.clip(0.5 + ratio_db / (2 * RESIDUAL_DB), 0.0, 1.0)

    def _reasons(self, bound: Vec, dev: float, alternatives: list[Alternative]) -> list[str]:
        out = []
        if math.isfinite(self.deviance_max) and not dev <= self.deviance_max:
            out.append(
                f"the map cannot explain the frame (deviance {dev:.3f}, the labelled frames' at most "
                f"{self.deviance_max:.3f}): not this radar's look, or not this target"
            )
        close = [a for a in alternatives if a.fit_gap < AMBIGUITY_GAP]
        if close:
            a = close[0]
            out.append(
                f"another attitude {a.distance_deg:.0f} deg away (z {a.angles_deg[0]:.1f}, y {a.angles_deg[1]:.1f}, x "
                f"{a.angles_deg[2]:.1f}) explains the image nearly as well: the frame cannot tell them apart"
            )
        if not np.all(np.isfinite(bound)) or float(np.max(bound)) > MAX_BOUND_DEG:
            worst = "z y x".split()[int(np.argmax(np.where(np.isfinite(bound), bound, 1e9)))]
            out.append(f"the 90 % bound on {worst} is over {MAX_BOUND_DEG:g} deg: the image barely constrains it")
        if not self.calibrated:
            out.append("the map's bounds are not calibrated (it was built without held-out labelled scenes)")
        return out
