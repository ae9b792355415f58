"""Serve the exported models with ONNX Runtime. Imports onnxruntime and numpy only (never torch).

``Estimator.load(model_dir)`` reads ``model_card.json``, checks every ONNX file
against its sha256 (a missing, truncated or altered file raises ModelFileError
naming it), and opens one session per network with tuned options: full graph
optimisation, a fixed intra-op thread count, sequential execution, no spin-waiting.
A stack of frames runs through the models in runs of at most ``run_batch`` frames.
On this 2-core machine the cost per frame barely depends on the run size (0.8-1.3x
that of single frames, run to run; BENCHMARKS.md), so the default of 4 is a choice
that bounds the memory of a run rather than a measured optimum.

``Estimator.estimate`` is safe to call from many threads at once, and gathers their
frames: one caller at a time runs the models, on every frame waiting when it starts
(up to ``run_batch``, whole requests), so a busy service runs batches of 4 instead
of eight competing batches of 1, and an idle one adds no wait at all.
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from inference.errors import ModelFileError
from inference.files import checked_file

DEFAULT_MODEL_DIR = Path(__file__).resolve().parent / "models" / "shipped"
DEFAULT_RUN_BATCH = 4
# A set's optional second UNet++, trained over every rotation, whose silhouettes the library search fits
# (``Estimator.search_enhancer``); the networks' own UNet++ stays the one Swin reads.
SEARCH_ROLE = "search_unetpp"


def read_card(model_dir: str | Path) -> dict[str, Any]:
    """Read and check a model card and the files it lists; raise ModelFileError naming any bad file."""
    d = Path(model_dir)
    card_path = d / "model_card.json"
    if not card_path.is_file():
        raise ModelFileError(f"model card {card_path} is missing", field="model")
    try:
        card: dict[str, Any] = json.loads(card_path.read_text())
    except json.JSONDecodeError as exc:
        raise ModelFileError(f"model card {card_path} is not JSON: {exc.msg}", field="model") from None
    for role in ("unetpp", "swin", SEARCH_ROLE):
        entry = card.get("files", {}).get(role)
        if not entry:
            if role == SEARCH_ROLE:  # optional: without it the library search fits the networks' own silhouettes
                continue
            raise ModelFileError(f"model card {card_path} lists no {role} file", field="model")
        checked_file(d / entry["file"], entry["sha256"], "model file")
    return card


SELFCHECK_POOL = 16  # the self-check compares UNet++'s output averaged over 16 x 16 blocks


def selfcheck_frames(size: int) -> np.ndarray:
    """The self-check's input [1, 1, size, size]: seeded uniform noise, the same on every machine."""
    return np.random.default_rng(0).random((1, 1, size, size), dtype=np.float32)


def pooled(enhanced: np.ndarray) -> np.ndarray:
    """UNet++'s output [N, 1, H, W] averaged over SELFCHECK_POOL x SELFCHECK_POOL blocks: [N, H/16, W/16]."""
    n, _, h, w = enhanced.shape
    p = SELFCHECK_POOL
    return np.asarray(enhanced[:, 0].reshape(n, h // p, p, w // p, p).mean(axis=(2, 4)))


def check_computes_here(selfcheck: dict[str, Any], unet_session: Any, model_dir: Path) -> None:
    """Refuse a UNet++ that computes here otherwise than torch did at export (``gsa export`` records it).

    Int8 kernels differ between CPUs: on an x86 CPU without VNNI onnxruntime adds pairs of
    uint8 x int8 products in int16, which 8-bit weights saturate. Such a UNet++ loads and runs
    and is wrong (silhouette IoU 0.90 instead of 0.99, Swin 18 deg instead of 2), so the
    service checks the file against the float network's output on a seeded noise frame
    before it answers anything. Measured on such a CPU: the 8-bit file is 0.28 off, the 7-bit
    one (``inference.export.quantize_int8``) 0.027, the tolerance 0.1.
    """
    expected = np.array(selfcheck["unetpp_pooled"], np.float32)
    x = selfcheck_frames(int(selfcheck["img_size"]))
    got = pooled(unet_session.run(None, {"frame": x})[0])
    off = float(np.abs(got - expected).max())
    if got.shape != expected.shape or off > float(selfcheck["tolerance"]):
        raise ModelFileError(
            f"UNet++ in {model_dir} computes differently on this CPU than the float network did when it was "
            f"exported (its output off by {off:.3f}, over {selfcheck['tolerance']}, on the card's check frame): "
            "export it again with this version's gsa export (int8 with 7-bit weights) or without --int8",
            field="model",
        )


def session_options(threads: int | None = None) -> Any:
    """The tuned ONNX Runtime options the service runs with (and the benchmarks measure).

    Full graph optimisation, sequential execution, ``threads`` intra-op threads (default:
    all cores), and no spin-waiting. Each session has its own thread pool; with spinning
    on, the pool of the network that just ran keeps its threads busy-waiting while the
    other network runs, which on 2 cores doubled the two-model time (design/measurements.md,
    "ONNX Runtime threads without spinning").
    """
    import os

    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    opts.intra_op_num_threads = threads or os.cpu_count() or 1
    opts.inter_op_num_threads = 1
    opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
    return opts


@dataclass(frozen=True)
class NetworkOutput:
    """What the networks answer for a batch (not yet fitted or checked): Euler z, y, x (deg), enhanced frames, and seconds per stage."""

    angles_deg: NDArray[np.float32]
    enhanced: NDArray[np.float32]
    timings_s: dict[str, float]


@dataclass(eq=False)  # jobs are told apart by identity, never by comparing their frames
class _Job:
    """One caller's frames waiting for a run, and what the run gave them."""

    frames: NDArray[np.float32]
    done: bool = False
    result: NetworkOutput | None = None
    error: BaseException | None = None


class Estimator:
    """UNet++ then Swin in ONNX Runtime."""

    def __init__(
        self, model_dir: Path, card: dict[str, Any], sessions: dict[str, Any], run_batch: int = DEFAULT_RUN_BATCH
    ) -> None:
        if run_batch < 1:
            raise ValueError(f"run_batch {run_batch} must be at least 1")
        self.model_dir = model_dir
        self.card = card
        self._sessions = sessions
        self.run_batch = run_batch
        self._cv = threading.Condition()
        self._pending: list[_Job] = []
        self._running = False  # one caller at a time runs the models for everyone waiting
        self.angle_scale_deg = float(card.get("angle_scale_deg", 45.0))
        # A Swin trained on raw frames (gsa train --no-enhance) reads the frames as they come.
        self.enhances = card.get("enhance", True) is not False
        self.img_size = int(card["config"]["img_size"])

    @classmethod
    def load(
        cls, model_dir: str | Path = DEFAULT_MODEL_DIR, threads: int | None = None, run_batch: int = DEFAULT_RUN_BATCH
    ) -> Estimator:
        import onnxruntime as ort

        d = Path(model_dir)
        card = read_card(d)
        opts = session_options(threads)
        sessions = {}
        for role in (r for r in ("unetpp", "swin", SEARCH_ROLE) if r in card["files"]):
            path = d / card["files"][role]["file"]
            # The search's UNet++ on one intra-op thread: the fit's threads call it, a frame each, one a core
            # (``Checker.check_many``).
            role_opts = session_options(1) if role == SEARCH_ROLE else opts
            try:
                sessions[role] = ort.InferenceSession(str(path), role_opts, providers=["CPUExecutionProvider"])
            except Exception as exc:  # onnxruntime raises its own exception types
                raise ModelFileError(f"model file {path} cannot be loaded: {exc}", field="model") from None
        if card.get("selfcheck"):
            check_computes_here(card["selfcheck"], sessions["unetpp"], d)
        if (card["files"].get(SEARCH_ROLE) or {}).get("selfcheck"):
            check_computes_here(card["files"][SEARCH_ROLE]["selfcheck"], sessions[SEARCH_ROLE], d)
        return cls(d, card, sessions, run_batch)

    @property
    def identity(self) -> dict[str, Any]:
        return {
            "name": self.card.get("name"),
            "config": self.card["config"]["name"],
            "unetpp_sha256": self.card["files"]["unetpp"]["sha256"],
            "swin_sha256": self.card["files"]["swin"]["sha256"],
            "search_unetpp_sha256": (self.card["files"].get(SEARCH_ROLE) or {}).get("sha256"),
            "trained_on": card_target(self.card),
            # an adapted version of the target's set (the service's /v1/model-sets); 0: the set as configured
            "version": int((self.card.get("version") or {}).get("number", 0)),
        }

    def _run(self, role: str, frames: NDArray[np.float32]) -> NDArray[np.float32]:
        """Run one network over frames [N, H, W] in runs of at most ``run_batch`` frames."""
        x = np.asarray(frames, np.float32)[:, None]
        step = self.run_batch
        outs = [self._sessions[role].run(None, {"frame": x[k : k + step]})[0] for k in range(0, max(len(x), 1), step)]
        return np.concatenate(outs) if len(outs) > 1 else np.asarray(outs[0])

    def enhance(self, frames: NDArray[np.float32]) -> NDArray[np.float32]:
        """Run UNet++ on normalised frames [N, H, W]; return enhanced frames [N, H, W].

        ``estimate`` skips this for models whose card says their Swin was trained on raw frames.
        """
        return np.asarray(self._run("unetpp", frames)[:, 0], np.float32)

    @property
    def search_enhancer(self) -> Callable[[NDArray[np.float32]], NDArray[np.float32]] | None:
        """The UNet++ whose silhouette the library search fits (``Checker.check``), or None for a set without one."""
        return self.search_enhance if SEARCH_ROLE in self._sessions else None

    def search_enhance(self, frame: NDArray[np.float32]) -> NDArray[np.float32]:
        """Run the search's UNet++ on one normalised frame [H, W] (thread-safe); return its enhanced frame [H, W]."""
        x = np.asarray(frame, np.float32)[None, None]
        return np.asarray(self._sessions[SEARCH_ROLE].run(None, {"frame": x})[0][0, 0], np.float32)

    def attitude(self, frames: NDArray[np.float32]) -> NDArray[np.float32]:
        """Run Swin on (enhanced) frames [N, H, W]; return Euler z, y, x in degrees [N, 3]."""
        return np.asarray(self._run("swin", frames) * self.angle_scale_deg, np.float32)

    def estimate(self, frames: NDArray[np.floating]) -> NetworkOutput:
        """Estimate attitudes of normalised frames [N, H, W] (``inference.frames.normalise_frame`` output).

        Thread-safe. Concurrent callers' frames share runs; each caller gets its own
        frames' results, with the stage times of the runs it was in shared out per frame.
        """
        job = _Job(np.asarray(frames, np.float32))
        with self._cv:
            self._pending.append(job)
            while self._running and not job.done:
                self._cv.wait()
            lead = not job.done
            self._running = self._running or lead
        if lead:
            try:  # this caller runs the models, for itself and whoever waits, until its own frames are done
                while not job.done:
                    self._run_jobs(self._take())
            finally:
                with self._cv:
                    self._running = False
                    self._cv.notify_all()
        if job.error is not None:
            raise job.error
        assert job.result is not None
        return job.result

    def _take(self) -> list[_Job]:
        """Take waiting requests in order, whole, up to ``run_batch`` frames (at least one request)."""
        with self._cv:
            shape = self._pending[0].frames.shape[1:]
            take: list[_Job] = []
            rest: list[_Job] = []
            n = 0
            for job in self._pending:
                if job.frames.shape[1:] == shape and (not take or n + len(job.frames) <= self.run_batch):
                    take.append(job)
                    n += len(job.frames)
                else:
                    rest.append(job)
            self._pending = rest
            return take

    def _run_jobs(self, jobs: list[_Job]) -> None:
        frames = np.concatenate([j.frames for j in jobs]) if len(jobs) > 1 else jobs[0].frames
        res: NetworkOutput | None = None
        error: BaseException | None = None
        try:
            t0 = time.perf_counter()
            enhanced = self.enhance(frames) if self.enhances else frames
            t1 = time.perf_counter()
            angles = self.attitude(enhanced)
            res = NetworkOutput(angles, enhanced, {"unetpp": t1 - t0, "swin": time.perf_counter() - t1})
        except Exception as exc:  # every request in the run gets the error; the estimator stays usable
            error = exc
        with self._cv:
            k = 0
            for j in jobs:
                n = len(j.frames)
                if res is not None:
                    share = n / max(len(frames), 1)
                    j.result = NetworkOutput(
                        res.angles_deg[k : k + n],
                        res.enhanced[k : k + n],
                        {stage: t * share for stage, t in res.timings_s.items()},
                    )
                j.error = error
                j.done = True
                k += n
            self._cv.notify_all()


# The target a card that names none was trained on (inference.simulation.targets.DEFAULT_TARGET; a test
# keeps the two equal without this module importing the simulator).
UNNAMED_CARD_TARGET = "tiangong-like"


def card_target(card: dict[str, Any]) -> str:
    """The target a model set was trained on: its card's, or the default target for older cards."""
    return str(card.get("target") or UNNAMED_CARD_TARGET)


class ModelSets:
    """The model sets a service runs, one per target they were trained on; one of them is the default.

    A request for a target with its own set is answered by that set's networks; any other
    target by the default set's (the fit then renders the asked target from Swin's answer).
    """

    def __init__(self, sets: dict[str, Estimator], default: str) -> None:
        if default not in sets:
            raise ValueError(f"default model set {default!r} is not among {sorted(sets)}")
        self.sets = sets
        self.default_name = default

    @classmethod
    def load(
        cls,
        default_dir: str | Path = DEFAULT_MODEL_DIR,
        extra_dirs: Sequence[str | Path] = (),
        threads: int | None = None,
        run_batch: int = DEFAULT_RUN_BATCH,
    ) -> ModelSets:
        """Load the default set and each extra directory's; refuse two sets of one target or of other frame sizes."""
        default = Estimator.load(default_dir, threads=threads, run_batch=run_batch)
        sets = {card_target(default.card): default}
        for d in extra_dirs:
            est = Estimator.load(d, threads=threads, run_batch=run_batch)
            name = card_target(est.card)
            if name in sets:
                raise ModelFileError(
                    f"model set {d} is trained on {name!r}, as {sets[name].model_dir} is: one set per target",
                    field="model",
                )
            if est.img_size != default.img_size:
                raise ModelFileError(
                    f"model set {d} takes {est.img_size} px frames, the default set {default.img_size} px: "
                    "every set must take the same frames",
                    field="model",
                )
            sets[name] = est
        return cls(sets, card_target(default.card))

    @property
    def default(self) -> Estimator:
        return self.sets[self.default_name]

    def for_target(self, target: str | None) -> Estimator:
        """The set trained on ``target``, or the default set when none is (its card names which: ``trained_on``)."""
        return self.sets.get(target or self.default_name, self.default)

    def describe(self) -> list[dict[str, Any]]:
        """Each set: the target it was trained on, whether it is the default, its folder and files."""
        return [
            {"target": name, "default": name == self.default_name, "dir": str(est.model_dir), **est.identity}
            for name, est in self.sets.items()
        ]
