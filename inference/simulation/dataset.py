"""Labelled ISAR data sets: deterministic, sharded, hashed; and the ``simulate`` command.

A data set directory holds ``shard-00000.npz`` ... and ``manifest.json``. Each shard
has, per frame: ``image`` (float16, the normalised magnitude the networks read),
``label`` (packed bits of the binary projection), ``angles_deg`` (z, y, x), ``snr_db``
and ``seed``. The manifest records every parameter, each shard's sha256 and a
content hash over them. Frame i's seed is derived from (seed, i) alone, so the data
are the same whatever the number of workers. The set is written to ``DIR.partial``
and renamed at the end: an interrupted run never leaves a set that looks complete.

Runs with numpy and scipy only (``python -m inference.simulation.dataset ...``), so a bare GPU
machine can make its own training data; ``--physics po`` also needs trimesh, embreex and numba.
"""

from __future__ import annotations

import argparse
import hashlib
import math
import os
import shutil
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from inference.engine import Engine, LocalEngine, engine_for
from inference.errors import DatasetError, module_main
from inference.files import read_json, sha256_file, write_json
from inference.frames import normalise_frame
from inference.simulation.meshes import load_model
from inference.simulation.radar import Imager, Radar
from inference.simulation.scene import (
    CENTRES_ONLY,
    DEFAULT_SCATTERING,
    PHYSICS,
    PO_ONLY,
    Scattering,
    check_fits,
    draw_scattering,
    mirror_pair_iou,
    po_mesh,
    simulate,
)
from inference.simulation.targets import TargetModel, tiangong_like

FORMAT_VERSION = 1


@dataclass(frozen=True, slots=True)
class DatasetSpec:
    """What to generate. ``attitudes`` "cube": the Euler angles uniform in [-max_angle_deg, max_angle_deg] on each
    axis (the paper's); "so3": attitudes uniform over all rotations (Haar measure), written as Euler angles z and x
    in (-180, 180], y in [-90, 90]."""

    n: int
    seed: int = 0
    snr_min_db: float | None = -3.0
    snr_max_db: float | None = 15.0
    max_angle_deg: float = 45.0
    shard_size: int = 250
    n_train: int | None = None  # the paper's split is n_train=4000 of 5000
    model_path: str | None = None
    model_scale: float = 1.0
    variety: str | None = None  # a VARIETY_PRESETS name: each frame draws its own Scattering (None: the default)
    variety_overrides: tuple[tuple[str, Any], ...] = ()
    # Under ``variety``, the share of frames drawn from the preset; the others are default frames, so a
    # set can teach the varied looks without giving up the default one (1.0: every frame varied).
    variety_share: float = 1.0
    # ``physics`` "po": frames by physical optics on the model's facets (inference/simulation/po.py), a share
    # ``physics_share`` of them (the rest default frames), each with ``po_bounces``, a roughness drawn
    # uniformly in ``po_roughness`` (low, high) and facets of ``po_facet_m``.
    physics: str = "centres"
    physics_share: float = 1.0
    po_bounces: int = 1
    po_roughness: tuple[float, float] = (0.0, 0.0)
    po_facet_m: float = 0.2
    attitudes: str = "cube"  # or "so3": see the class's docstring
    # Under "so3", the share of frames drawn over every rotation; the others in the cube (a set that teaches
    # UNet++ every attitude while Swin keeps learning the cube it answers: inference/training/train.py).
    so3_share: float = 1.0

    def __post_init__(self) -> None:
        if not isinstance(self.n, int) or self.n <= 0:
            raise DatasetError(f"n must be a positive integer, got {self.n}", field="n")
        if self.n > 10_000_000:
            raise DatasetError(f"n {self.n} is over the limit of 10,000,000", field="n")
        if (self.snr_min_db is None) != (self.snr_max_db is None):
            raise DatasetError("give both ends of the SNR range, or neither for noise-free frames", field="snr_db")
        if self.snr_min_db is not None and self.snr_max_db is not None:
            if not (math.isfinite(self.snr_min_db) and math.isfinite(self.snr_max_db)):
                raise DatasetError("SNR range must be finite", field="snr_db")
            if self.snr_min_db > self.snr_max_db:
                raise DatasetError(
                    f"SNR range {self.snr_min_db}:{self.snr_max_db} dB is inverted; write LOW:HIGH", field="snr_db"
                )
        if not 0.0 <= self.max_angle_deg <= 89.0:
            raise DatasetError(f"max_angle_deg {self.max_angle_deg} is outside [0, 89]", field="max_angle_deg")
        if self.attitudes not in ATTITUDES:
            raise DatasetError(
                f"attitudes {self.attitudes!r}: one of {', '.join(ATTITUDES)} (the +-max_angle_deg cube, or every "
                "rotation)",
                field="attitudes",
            )
        if not (isinstance(self.so3_share, (int, float)) and 0.0 < self.so3_share <= 1.0):
            raise DatasetError(
                f"so3_share {self.so3_share} must be in (0, 1]: the share of frames drawn over every rotation",
                field="so3_share",
            )
        if self.so3_share < 1.0 and self.attitudes != "so3":
            raise DatasetError("so3_share needs attitudes so3 (--attitudes so3)", field="so3_share")
        if self.shard_size <= 0:
            raise DatasetError("shard_size must be positive", field="shard_size")
        if not (isinstance(self.variety_share, (int, float)) and 0.0 < self.variety_share <= 1.0):
            raise DatasetError(
                f"variety_share {self.variety_share} must be in (0, 1]: the share of frames drawn from the preset",
                field="variety_share",
            )
        if self.variety_share < 1.0 and self.variety is None:
            raise DatasetError(
                "variety_share needs a variety preset to draw from (--variety robust)", field="variety_share"
            )
        if self.variety is not None:
            draw_scattering(self.variety, np.random.default_rng(0), dict(self.variety_overrides))  # fails early
        if self.physics not in PHYSICS:
            raise DatasetError(f"unknown physics {self.physics!r}; one of {', '.join(PHYSICS)}", field="physics")
        if not (isinstance(self.physics_share, (int, float)) and 0.0 < self.physics_share <= 1.0):
            raise DatasetError(
                f"physics_share {self.physics_share} must be in (0, 1]: the share of frames made by --physics",
                field="physics_share",
            )
        lo, hi = self.po_roughness
        if not 0.0 <= lo <= hi <= 1.0:
            raise DatasetError(f"roughness {lo}:{hi} must be LOW:HIGH within [0, 1]", field="roughness")
        if self.physics == "centres" and (
            self.physics_share < 1.0
            or (self.po_bounces, hi, self.po_facet_m) != (PO_ONLY["bounces"], PO_ONLY["roughness"], PO_ONLY["facet_m"])
        ):
            raise DatasetError(
                "--physics-share, --bounces, --roughness and --facet-m belong to --physics po", field="physics"
            )
        if self.physics == "po":
            Scattering(physics="po", bounces=self.po_bounces, roughness=hi, facet_m=self.po_facet_m)  # fails early
        if self.n_train is not None and not 0 <= self.n_train <= self.n:
            raise DatasetError(f"n_train {self.n_train} must be within [0, n={self.n}]", field="n_train")


ATTITUDES = ("cube", "so3")


def uniform_rotation_angles(rng: np.random.Generator) -> tuple[float, float, float]:
    """Euler angles (z, y, x deg) of a rotation drawn uniformly over SO(3): a unit quaternion from four normal
    draws is uniform on the 3-sphere, and so its rotation under the Haar measure (Shoemake)."""
    from inference.rotations import euler_from_matrix, quaternion_matrix

    q = rng.standard_normal(4)
    return euler_from_matrix(quaternion_matrix(q / np.linalg.norm(q)))


def frame_seed(seed: int, index: int) -> int:
    """Return the seed of frame ``index``: a function of (seed, index) only."""
    digest = hashlib.sha256(f"gsa-isar:{seed}:{index}".encode()).digest()
    return int.from_bytes(digest[:8], "little") >> 1


def frame_truth(spec: DatasetSpec, index: int) -> tuple[tuple[float, float, float], float | None, int]:
    """Return the angles (z, y, x deg), SNR (dB or None) and seed of frame ``index``."""
    s = frame_seed(spec.seed, index)
    rng = np.random.default_rng(s)
    if spec.attitudes == "so3" and is_over_so3(spec, s):
        angles: tuple[float, ...] = uniform_rotation_angles(rng)
    else:
        angles = tuple(float(a) for a in rng.uniform(-spec.max_angle_deg, spec.max_angle_deg, 3))
    snr = None
    if spec.snr_min_db is not None and spec.snr_max_db is not None:
        snr = float(rng.uniform(spec.snr_min_db, spec.snr_max_db))
    return (angles[0], angles[1], angles[2]), snr, s


def is_over_so3(spec: DatasetSpec, frame_seed: int) -> bool:
    """Whether the frame of this seed draws its attitude over every rotation (``so3_share``; a stream of its own,
    so a set with a share of 1 is what it was before the share existed)."""
    return spec.so3_share >= 1.0 or float(np.random.default_rng([frame_seed, 3]).uniform()) < spec.so3_share


def is_varied(spec: DatasetSpec, frame_seed: int) -> bool:
    """Whether the frame of this seed draws its scattering from the spec's variety preset (``variety_share``).

    The coin comes from a stream of its own, so with a share of 1 a set is what it was before the
    share existed, and a varied frame's scattering is the same whatever the share.
    """
    if spec.variety is None:
        return False
    return spec.variety_share >= 1.0 or float(np.random.default_rng([frame_seed, 2]).uniform()) < spec.variety_share


def build_model(spec: DatasetSpec, radar: Radar) -> TargetModel:
    model = tiangong_like() if spec.model_path is None else load_model(spec.model_path, spec.model_scale)
    check_fits(model, radar)
    if spec.physics == "po":
        po_mesh(model)  # a point cloud or an unusable mesh fails here, before any work
    return model


def frame_scattering(spec: DatasetSpec, frame_seed: int) -> Scattering:
    """Return the scattering of the frame of this seed: the default, a variety draw, physical optics, or both.

    The variety and the physics each draw from a stream of their own, so a frame's angles, SNR and
    seed stay the default set's. A PO frame keeps a variety draw's window, imaging and errors and
    drops what belongs to the scattering-centre physics.
    """
    sc = DEFAULT_SCATTERING
    if spec.variety is not None and is_varied(spec, frame_seed):
        sc = draw_scattering(spec.variety, np.random.default_rng([frame_seed, 1]), dict(spec.variety_overrides))
    if spec.physics == "po":
        rng = np.random.default_rng([frame_seed, 3])
        if spec.physics_share >= 1.0 or float(rng.uniform()) < spec.physics_share:
            lo, hi = spec.po_roughness
            sc = replace(
                sc,
                **CENTRES_ONLY,
                physics="po",
                bounces=spec.po_bounces,
                roughness=float(rng.uniform(lo, hi)) if hi > lo else lo,
                facet_m=spec.po_facet_m,
            )
    return sc


def render_frames(
    spec: DatasetSpec, radar: Radar, start: int, stop: int, model: TargetModel | None = None
) -> dict[str, NDArray[Any]]:
    """Simulate frames ``start``..``stop - 1`` of the set; return the arrays of one shard."""
    model = model or build_model(spec, radar)
    imager = Imager(radar)
    n = stop - start
    images = np.empty((n, radar.n_range, radar.n_azimuth), np.float16)
    labels = np.empty((n, radar.n_range, radar.n_azimuth // 8), np.uint8)
    angles = np.empty((n, 3), np.float32)
    snrs = np.full(n, np.nan, np.float32)
    seeds = np.empty(n, np.int64)
    for k, index in enumerate(range(start, stop)):
        ang, snr, s = frame_truth(spec, index)
        frame = simulate(model, imager, ang, snr, s, frame_scattering(spec, s))
        images[k] = normalise_frame(np.abs(frame.image))
        labels[k] = np.packbits(frame.label, axis=1)
        angles[k] = ang
        snrs[k] = np.nan if snr is None else snr
        seeds[k] = s
    return {
        "image": images,
        "label": labels,
        "angles_deg": angles,
        "snr_db": snrs,
        "seed": seeds,
        "index": np.arange(start, stop),
    }


SHARD_TIME = (1980, 1, 1, 0, 0, 0)  # every member's zip time: a shard's bytes are its arrays' alone


def shard_bytes(arrays: dict[str, NDArray[Any]]) -> bytes:
    """An ``.npz`` of ``arrays`` (``np.load`` reads it) whose bytes depend on the arrays alone, made in memory so a
    Ray task can hand it back. Every member carries one fixed zip time, stated here rather than left to
    ``zipfile``'s default for members opened by name (which ``np.savez`` relies on).
    """
    import io
    import zipfile

    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_STORED, allowZip64=True) as zf:
        for key, value in arrays.items():
            info = zipfile.ZipInfo(key + ".npy", date_time=SHARD_TIME)
            with zf.open(info, "w", force_zip64=True) as fid:
                np.lib.format.write_array(fid, np.asanyarray(value), allow_pickle=False)
    return buf.getvalue()


def _render_shard(args: tuple[DatasetSpec, Radar, int, int]) -> bytes:
    """One shard's file contents: a pure function of its arguments (run here, in a process pool or as a Ray task)."""
    spec, radar, start, stop = args
    return shard_bytes(render_frames(spec, radar, start, stop))


def _write_atomic(path: Path, data: bytes) -> str:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_bytes(data)
    tmp.rename(path)
    return hashlib.sha256(data).hexdigest()


def generate(
    spec: DatasetSpec,
    out: str | Path,
    radar: Radar | None = None,
    workers: int | None = None,
    progress: bool = True,
    engine: Engine | None = None,
    on_shard: Callable[[int, int], None] | None = None,
    resume: bool = False,
) -> dict[str, Any]:
    """Generate the data set into ``out`` (which must not exist) and return its manifest.

    ``engine`` runs the shards (default: ``workers`` local processes; a Ray cluster gives the same bytes);
    ``on_shard(done, total)`` hears of each shard written (it may raise to stop the work). With ``resume``, the
    shards a stopped run already wrote to ``OUT.partial`` are kept (each was written whole, then renamed).
    """
    radar = radar or Radar()
    out = Path(out)
    if out.exists():
        raise DatasetError(f"{out} already exists; choose a new directory", field="out")
    model = build_model(spec, radar)  # fail on a bad model before any work
    partial = out.with_name(out.name + ".partial")
    if partial.exists() and not resume:
        shutil.rmtree(partial)
    partial.mkdir(parents=True, exist_ok=True)
    bounds = [(s, min(s + spec.shard_size, spec.n)) for s in range(0, spec.n, spec.shard_size)]
    names = [f"shard-{k:05d}.npz" for k in range(len(bounds))]
    kept = {name: sha256_file(partial / name) for name in names if (partial / name).is_file()}
    todo = [k for k, name in enumerate(names) if name not in kept]
    engine = engine or LocalEngine(max(1, min(workers or os.cpu_count() or 1, len(todo) or 1)))
    t0 = time.perf_counter()
    done = sum(e - s for name, (s, e) in zip(names, bounds, strict=True) if name in kept)
    already = done
    try:
        pieces = engine.map(_render_shard, [(spec, radar, *bounds[k]) for k in todo])
        for k, data in zip(todo, pieces, strict=True):
            kept[names[k]] = _write_atomic(partial / names[k], data)
            done += bounds[k][1] - bounds[k][0]
            _progress(progress, done, spec.n, t0)
            if on_shard is not None:
                on_shard(done, spec.n)
    except BaseException:
        if not resume:
            shutil.rmtree(partial, ignore_errors=True)
        raise
    shards = [{"file": name, "sha256": kept[name], "frames": e - s} for name, (s, e) in zip(names, bounds, strict=True)]
    elapsed = time.perf_counter() - t0
    manifest = {
        "format_version": FORMAT_VERSION,
        "spec": asdict(spec),
        "radar": asdict(radar),
        "model": {
            "name": model.name,
            "description": model.description,
            "radius_m": model.radius_m,
            "scatterers": int(len(model.scatterers)),
            "mirror_planes": model.mirror_planes,
            "symmetries": model.symmetries(),
            "mirror_pair_label_iou": mirror_pair_iou(model, Imager(radar), n=32),
            "mesh_sha256": sha256_file(Path(spec.model_path)) if spec.model_path else None,
            "scale": spec.model_scale,
        },
        "frames": spec.n,
        "split": {"train": [0, spec.n_train], "test": [spec.n_train, spec.n]} if spec.n_train is not None else None,
        "normalisation": "inference.frames.normalise_frame (40 dB below the 99.5th percentile)",
        "shards": shards,
        "content_sha256": hashlib.sha256("".join(str(s["sha256"]) for s in shards).encode()).hexdigest(),
        "generated_in_s": round(elapsed, 2),
        "frames_per_s": round((spec.n - already) / elapsed, 1),
        "workers": engine.workers,
        "engine": engine.name,
    }
    write_json(partial / "manifest.json", manifest)
    partial.rename(out)
    return manifest


def _progress(show: bool, done: int, total: int, t0: float) -> None:
    if not show:
        return
    rate = done / max(time.perf_counter() - t0, 1e-9)
    eta = (total - done) / rate if rate > 0 else float("nan")
    print(f"simulate: {done}/{total} frames, {rate:.0f} frames/s, {eta:.0f} s left", file=sys.stderr, flush=True)


def load_manifest(data_dir: str | Path, verify: bool = True) -> dict[str, Any]:
    """Read a data set's manifest; with ``verify``, check every shard exists and matches its sha256.

    Raises DatasetError naming the problem before any work is done.
    """
    d = Path(data_dir)
    path = d / "manifest.json"
    if not path.is_file():
        raise DatasetError(f"{d} has no manifest.json: not a data set (make one with `gsa simulate`)", field="data")
    manifest: dict[str, Any] = read_json(path, DatasetError, "data")
    if manifest.get("format_version") != FORMAT_VERSION or not manifest.get("shards"):
        raise DatasetError(f"{path} is not a version-{FORMAT_VERSION} manifest with shards", field="data")
    if verify:
        for shard in manifest["shards"]:
            f = d / shard["file"]
            if not f.is_file():
                raise DatasetError(f"shard {f} listed in the manifest is missing", field="data")
            if sha256_file(f) != shard["sha256"]:
                raise DatasetError(f"shard {f} does not match its sha256 in the manifest", field="data")
    return manifest


def load_arrays(data_dir: str | Path, verify: bool = True) -> dict[str, NDArray[Any]]:
    """Load a whole data set into memory (labels unpacked to bool)."""
    d = Path(data_dir)
    manifest = load_manifest(d, verify)
    parts: dict[str, list[NDArray[Any]]] = {}
    for shard in manifest["shards"]:
        with np.load(d / shard["file"]) as z:
            for key in z.files:
                parts.setdefault(key, []).append(z[key])
    out = {k: np.concatenate(v) for k, v in parts.items()}
    out["label"] = np.unpackbits(out["label"], axis=2).astype(bool)
    return out


def load_range(
    data_dir: str | Path, start: int, stop: int, keys: tuple[str, ...] = ("image", "angles_deg"), verify: bool = True
) -> dict[str, NDArray[Any]]:
    """Load frames ``start``..``stop - 1`` of a data set, reading only the shards that hold them."""
    d = Path(data_dir)
    manifest = load_manifest(d, verify)
    parts: dict[str, list[NDArray[Any]]] = {k: [] for k in keys}
    first = 0
    for shard in manifest["shards"]:
        lo, hi = max(start, first), min(stop, first + shard["frames"])
        if lo < hi:
            with np.load(d / shard["file"]) as z:
                for key in keys:
                    parts[key].append(z[key][lo - first : hi - first])
        first += shard["frames"]
    if not parts[keys[0]]:
        raise DatasetError(f"{d} holds {first} frames; frames {start}..{stop - 1} are not in it", field="data")
    return {k: np.concatenate(v) for k, v in parts.items()}


def preview(spec: DatasetSpec, path: str | Path, radar: Radar | None = None, count: int = 6) -> None:
    """Draw ``count`` frames of the set beside their labels (like the paper's Figure 9) to a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    radar = radar or Radar()
    arrays = render_frames(spec, radar, 0, min(count, spec.n))
    n = len(arrays["index"])
    fig, axes = plt.subplots(2, n, figsize=(2.6 * n, 5.6), squeeze=False)
    extent = [-radar.extent_m[1] / 2, radar.extent_m[1] / 2, radar.extent_m[0] / 2, -radar.extent_m[0] / 2]
    for k in range(n):
        z, y, x = arrays["angles_deg"][k]
        snr = arrays["snr_db"][k]
        axes[0, k].imshow(arrays["image"][k].astype(np.float32), cmap="gray", extent=extent, vmin=0, vmax=1)
        axes[0, k].set_title(
            f"z {z:.0f} y {y:.0f} x {x:.0f}\n" + ("noise-free" if np.isnan(snr) else f"{snr:.1f} dB"), fontsize=8
        )
        axes[1, k].imshow(np.unpackbits(arrays["label"][k], axis=1), cmap="gray", extent=extent)
        for ax in axes[:, k]:
            ax.set_xlabel("cross-range (m)", fontsize=7)
            ax.tick_params(labelsize=6)
    axes[0, 0].set_ylabel("ISAR frame\nrange (m)", fontsize=8)
    axes[1, 0].set_ylabel("label\nrange (m)", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def parse_snr(text: str) -> tuple[float | None, float | None]:
    """Parse 'LOW:HIGH' (dB), a single value, or 'none'."""
    if text.strip().lower() == "none":
        return None, None
    try:
        if ":" in text:
            lo, hi = (float(x) for x in text.split(":", 1))
        else:
            lo = hi = float(text)
    except ValueError:
        raise DatasetError(f"--snr-db {text!r}: write LOW:HIGH in dB, e.g. -3:15, or 'none'", field="snr_db") from None
    return lo, hi


TRAIN_SHARE = 0.8  # the paper's split: the first 80 % of frames train, the last 20 % test


def default_train_frames(n: int) -> int:
    """Return how many of ``n`` frames train under the paper's split (the rest test).

    >>> default_train_frames(5000), default_train_frames(7)
    (4000, 6)
    """
    return int(round(TRAIN_SHARE * n))


def split_ranges(manifest: dict[str, Any]) -> tuple[tuple[int, int], tuple[int, int]]:
    """Return a data set's ``(train, test)`` frame ranges ``[lo, hi)``: its manifest's split, else the paper's.

    The one split rule: training, export's calibration and ``gsa evaluate`` all read it here.

    >>> split_ranges({"frames": 7})
    ((0, 6), (6, 7))
    """
    split = manifest.get("split")
    if split:
        (a, b), (c, d) = split["train"], split["test"]
        return (int(a), int(b)), (int(c), int(d))
    n = int(manifest["frames"])
    cut = default_train_frames(n)
    return (0, cut), (cut, n)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--n", type=int, default=5000, help="number of frames (default 5000)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--snr-db", default="-3:15", help="SNR range LOW:HIGH in dB, or 'none' (default -3:15)")
    p.add_argument("--max-angle-deg", type=float, default=45.0, help="each Euler angle within +-this (cube)")
    p.add_argument(
        "--attitudes",
        default="cube",
        help="cube: Euler angles within --max-angle-deg (default); so3: uniform over every rotation",
    )
    p.add_argument(
        "--so3-share",
        type=float,
        default=1.0,
        help="with --attitudes so3: the share of frames over every rotation, the rest in the cube (default 1)",
    )
    p.add_argument("--split", action="store_true", help="the paper's split: first 80%% train, last 20%% test")
    p.add_argument("--n-train", type=int, help="split after this many training frames (the rest are the test set)")
    p.add_argument("--shard-size", type=int, default=250)
    p.add_argument("--workers", type=int, default=None, help="processes (default: all cores)")
    p.add_argument("--model", help="an OBJ or PLY target model (default: the built-in Tiangong-like station)")
    p.add_argument(
        "--model-scale", type=float, default=1.0, help="multiply the model's coordinates (e.g. 0.001 for mm)"
    )
    p.add_argument("--bandwidth-hz", type=float, default=1.6e9)
    p.add_argument("--carrier-hz", type=float, default=15e9)
    p.add_argument("--n-range", type=int, default=256)
    p.add_argument("--n-azimuth", type=int, default=256)
    p.add_argument("--aperture-deg", type=float, default=5.1)
    p.add_argument(
        "--variety",
        help="draw each frame's scattering from a preset (robust: inference.simulation.scene.VARIETY_PRESETS)",
    )
    p.add_argument(
        "--variety-set",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="fix one scattering parameter under --variety, e.g. window=none or edge_gain=0 (repeatable)",
    )
    p.add_argument(
        "--variety-share",
        type=float,
        default=1.0,
        metavar="P",
        help="under --variety, the share of frames drawn from the preset; the rest are default frames (default 1)",
    )
    p.add_argument(
        "--physics",
        default="centres",
        help="centres (the scattering-centre simulator, default) or po (physical optics on the model's facets)",
    )
    p.add_argument(
        "--physics-share",
        type=float,
        default=1.0,
        metavar="P",
        help="under --physics po, the share of frames made by PO; the rest are default frames (default 1)",
    )
    p.add_argument("--bounces", type=int, default=1, help="under --physics po: 1, or 2-3 (shooting and bouncing rays)")
    p.add_argument(
        "--roughness",
        default="0",
        help="under --physics po: Lambert's gamma of a diffuse term per facet, G or LOW:HIGH drawn per frame (0-1)",
    )
    p.add_argument("--facet-m", type=float, default=0.2, help="under --physics po: facet size in metres (default 0.2)")
    p.add_argument("--out", help="new directory for the data set")
    p.add_argument("--preview", metavar="PNG", help="draw a few frames beside their labels instead")


def parse_override(text: str) -> tuple[str, Any]:
    """Parse NAME=VALUE (a number, or a word such as none / hamming / dense)."""
    name, sep, value = text.partition("=")
    if not sep or not name:
        raise DatasetError(f"--variety-set {text!r}: write NAME=VALUE, e.g. window=none", field="variety")
    for kind in (int, float):
        try:
            return name.strip(), kind(value)
        except ValueError:
            continue
    return name.strip(), value.strip()


def parse_roughness(text: str) -> tuple[float, float]:
    """Parse G or LOW:HIGH (Lambert's gamma, 0-1)."""
    lo, sep, hi = str(text).partition(":")
    try:
        low = float(lo)
        high = float(hi) if sep else low
    except ValueError:
        raise DatasetError(
            f"--roughness {text!r}: write a number or LOW:HIGH, e.g. 0.2 or 0:0.5", field="roughness"
        ) from None
    return low, high


def run(args: argparse.Namespace) -> int:
    """Run the simulate command from parsed arguments; raises InferenceError on bad input."""
    lo, hi = parse_snr(args.snr_db)
    if args.split and args.n_train is not None:
        raise DatasetError("give --split (80 % train) or --n-train N, not both", field="n_train")
    n_train = default_train_frames(args.n) if args.split else args.n_train
    if args.variety_set and not args.variety:
        raise DatasetError("--variety-set needs --variety PRESET", field="variety")
    spec = DatasetSpec(
        args.n,
        args.seed,
        lo,
        hi,
        args.max_angle_deg,
        args.shard_size,
        n_train,
        args.model,
        args.model_scale,
        args.variety,
        tuple(parse_override(v) for v in args.variety_set),
        args.variety_share,
        args.physics,
        args.physics_share,
        args.bounces,
        parse_roughness(args.roughness),
        args.facet_m,
        args.attitudes,
        args.so3_share,
    )
    radar = Radar(args.carrier_hz, args.bandwidth_hz, args.n_range, args.n_azimuth, args.aperture_deg)
    if args.preview:
        build_model(spec, radar)
        preview(spec, args.preview, radar)
        print(f"preview written to {args.preview}")
        return 0
    if not args.out:
        raise DatasetError("give --out DIR for the data set (or --preview PNG)", field="out")
    m = generate(spec, args.out, radar, engine=engine_for(workers=args.workers))
    print(
        f"{m['frames']} frames in {args.out} ({m['frames_per_s']} frames/s, content sha256 {m['content_sha256'][:16]})"
    )
    return 0


def main(argv: list[str] | None = None) -> int:
    return module_main(
        "simulation.dataset", "simulate", add_arguments, run, argv, description="simulate a labelled ISAR data set"
    )


if __name__ == "__main__":
    sys.exit(main())
