"""Uploads to frames, frames to stored estimates, and attitudes in the frames operators fly in."""

from __future__ import annotations

import hashlib
import io
import math
import os
import struct
import threading
import zipfile
import zlib
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.core.security import private_dir, write_private
from app.errors import InputError
from inference.frames import euler_from_matrix, euler_to_quaternion, normalise_frame, rotation_matrix

MAX_NPZ_MEMBER_BYTES = 64 * 1024 * 1024  # decompressed; refuses zip bombs before reading them


@dataclass(frozen=True, slots=True)
class Upload:
    """One decoded frame: the magnitude image and what it came from."""

    name: str
    sha256: str
    shape: tuple[int, ...]
    dtype: str
    magnitude: NDArray[np.float64]


def _loc(name: str) -> list[str | int]:
    return ["file", name]


DEFAULT_MAX_SIDE = 4096


def _check_side(shape: tuple[int, ...], name: str, max_side: int) -> None:
    if shape and max(shape[-2:]) > max_side:
        raise InputError(
            _loc(name),
            f"frame of {list(shape)} is over the image size limit of {max_side} pixels a side (GSA_MAX_IMAGE_SIDE)",
        )


def _check_array(arr: NDArray[Any], name: str) -> NDArray[np.float64]:
    """Check a decoded frame (its side was checked from the file's header) and return its magnitude."""
    if arr.dtype.kind not in "biufc":
        raise InputError(_loc(name), f"unsupported dtype {arr.dtype}; send real or complex numbers")
    if arr.ndim != 2:
        raise InputError(_loc(name), f"a frame must be a 2-D array; this one has shape {list(arr.shape)}")
    if arr.size == 0:
        raise InputError(_loc(name), "the frame is empty")
    mag = np.abs(arr.astype(np.complex128 if arr.dtype.kind == "c" else np.float64))
    if not np.all(np.isfinite(mag)):
        raise InputError(_loc(name), "the frame contains NaN or infinite values")
    if not np.any(mag):
        raise InputError(_loc(name), "the frame is all zero: there is no echo to estimate an attitude from")
    if float(mag.max()) == float(mag.min()):
        raise InputError(_loc(name), "the frame is constant: there is no structure to estimate an attitude from")
    return np.asarray(mag, np.float64)


def _npy(data: bytes, name: str, max_side: int = DEFAULT_MAX_SIDE) -> NDArray[Any]:
    """Read a .npy array after checking its header against the bytes that follow (numpy allocates first)."""
    buf = io.BytesIO(data)
    try:
        version = np.lib.format.read_magic(buf)
        if version == (1, 0):
            shape, _fortran, dtype = np.lib.format.read_array_header_1_0(buf)
        elif version in ((2, 0), (3, 0)):
            shape, _fortran, dtype = np.lib.format.read_array_header_2_0(buf)
        else:
            raise ValueError(f"unsupported .npy version {version}")
    except (ValueError, OSError, EOFError, SyntaxError, TypeError) as exc:
        raise InputError(_loc(name), f"not a readable .npy array: {exc}") from None
    if dtype.hasobject:
        raise InputError(_loc(name), f"unsupported dtype {dtype}; send real or complex numbers")
    if len(shape) > 3 or any(int(d) < 0 for d in shape):
        raise InputError(_loc(name), f"a frame must be a 2-D array (or a 3-D stack); this one has shape {list(shape)}")
    _check_side(tuple(int(d) for d in shape), name, max_side)
    need = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
    if need != len(data) - buf.tell():
        raise InputError(
            _loc(name),
            f"the .npy header promises {need} bytes of {dtype} {list(shape)} but {len(data) - buf.tell()} follow",
        )
    try:
        buf.seek(0)
        return np.load(buf, allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:
        raise InputError(_loc(name), f"not a readable .npy array: {exc}") from None


def _npz_arrays(data: bytes, name: str, max_side: int = DEFAULT_MAX_SIDE) -> list[tuple[str, NDArray[Any]]]:
    try:
        with zipfile.ZipFile(io.BytesIO(data)) as zf:
            members = zf.infolist()
            if not members:
                raise InputError(_loc(name), "the .npz archive is empty")
            for m in members:
                if m.file_size > MAX_NPZ_MEMBER_BYTES:
                    raise InputError(
                        _loc(name), f"{m.filename} unpacks to {m.file_size} bytes, over {MAX_NPZ_MEMBER_BYTES}"
                    )
            if len(members) > 4096:
                raise InputError(_loc(name), f"the .npz archive holds {len(members)} members; at most 4096")
            total = sum(m.file_size for m in members)
            if total > 4 * MAX_NPZ_MEMBER_BYTES:
                raise InputError(
                    _loc(name), f"the .npz archive unpacks to {total} bytes, over {4 * MAX_NPZ_MEMBER_BYTES}"
                )
            return [(m.filename.removesuffix(".npy"), _npy(zf.read(m), name, max_side)) for m in members]
    except (zipfile.BadZipFile, zipfile.LargeZipFile, NotImplementedError, EOFError, OSError, RuntimeError,
            zlib.error) as exc:  # fmt: skip
        raise InputError(_loc(name), f"not a readable .npz archive: {exc}") from None


def _image(data: bytes, name: str, max_side: int = DEFAULT_MAX_SIDE) -> NDArray[Any]:
    from PIL import Image, UnidentifiedImageError

    try:
        img = Image.open(io.BytesIO(data))
        _check_side((img.size[1], img.size[0]), name, max_side)  # before decoding a single pixel
        img.load()
    except (UnidentifiedImageError, OSError, ValueError, SyntaxError, Image.DecompressionBombError) as exc:
        raise InputError(_loc(name), f"not a readable PNG or TIFF image: {exc}") from None
    frames = int(getattr(img, "n_frames", 1))
    if frames > 1:
        kind = "an animated PNG" if img.format == "PNG" else "a multi-page TIFF"
        raise InputError(
            _loc(name),
            f"{kind} of {frames} frames: send one frame per image, or the frames as a .npz stack to the batch",
        )
    if img.mode not in ("L", "I;16", "I;16B", "I;16L"):
        raise InputError(_loc(name), f"image mode {img.mode} is not 8- or 16-bit grayscale")
    arr = np.asarray(img)
    if arr.dtype.kind not in "ui" or arr.dtype.itemsize > 2:
        raise InputError(_loc(name), f"image of dtype {arr.dtype} is not 8- or 16-bit grayscale")
    return arr


def decode(data: bytes, name: str, allow_stack: bool = True, max_side: int = DEFAULT_MAX_SIDE) -> list[Upload]:
    """Decode an upload (.npy, .npz, .png, .tif/.tiff) into frames; with ``allow_stack``, arrays [N, H, W] too."""
    if not data:
        raise InputError(_loc(name), "the file is empty")
    digest = hashlib.sha256(data).hexdigest()
    head = data[:8]
    if head.startswith(b"\x93NUMPY"):
        arrays = [(name, _npy(data, name, max_side))]
    elif head.startswith(b"PK"):
        arrays = _npz_arrays(data, name, max_side)
    elif head.startswith(b"\x89PNG") or head[:4] in (b"II*\x00", b"MM\x00*"):
        arrays = [(name, _image(data, name, max_side))]
    else:
        raise InputError(_loc(name), "unknown format: send .npy, .npz, or 8/16-bit grayscale PNG or TIFF")
    out = []
    for label, arr in arrays:
        stack = arr if arr.ndim == 3 and allow_stack else arr[None] if arr.ndim == 2 else None
        if stack is None:
            if arr.ndim == 3:
                raise InputError(
                    _loc(name),
                    f"a frame must be a 2-D array; this one has shape {list(arr.shape)} "
                    "(send stacks [N, H, W] to /v1/estimates/batch)",
                )
            _check_array(arr, name)  # raises with the shape
            continue
        for k, frame in enumerate(stack):
            frame_name = name if len(stack) == 1 and len(arrays) == 1 else f"{name}:{label}[{k}]"
            out.append(Upload(frame_name, digest, tuple(frame.shape), str(arr.dtype), _check_array(frame, name)))
    return out


NORMALISED_MIN_TOP_SHARE = 0.004  # normalise_frame clips the top 0.5 % of pixels to 1.0 (a margin for ties)


def resample_metres(
    mag: NDArray[np.float64], cells_m: tuple[float, float], model_cells_m: tuple[float, float], size: int
) -> NDArray[np.float64]:
    """Resample a frame of cells ``cells_m`` (range, cross-range metres) to the models' cells, centred, ``size`` a side.

    Bilinear; the frame's centre pixel (N/2, counted from 0) stays the centre. Where the frame
    covers less than the models' frame (24 x 29 m for the shipped models), the rest is its median
    (its noise floor).
    """
    from scipy.ndimage import affine_transform

    model = model_cells_m
    scale = (model[0] / cells_m[0], model[1] / cells_m[1])  # input pixels per model pixel
    spans = (mag.shape[0] / scale[0], mag.shape[1] / scale[1])
    if min(spans) < 8:
        raise InputError(
            ["range_cell_m"],
            f"a {mag.shape[0]}x{mag.shape[1]} frame of {cells_m[0]:g} x {cells_m[1]:g} m cells covers under 8 of the "
            f"models' {model[0]:.4f} x {model[1]:.4f} m pixels: check the cell sizes",
        )
    centre_in = np.array([mag.shape[0] // 2, mag.shape[1] // 2], float)
    offset = centre_in - np.array(scale) * (size // 2)
    out = affine_transform(mag, scale, offset=offset, output_shape=(size, size), order=1, mode="constant",
                           cval=float(np.median(mag)))  # fmt: skip
    return np.asarray(out, np.float64)


def prepare(upload: Upload, size: int, resample: bool, normalised: bool = False,
            cells_m: tuple[float, float] | None = None,
            model_cells_m: tuple[float, float] | None = None) -> NDArray[np.float32]:  # fmt: skip
    """Return the normalised frame the models take: the training normalisation, resampled if asked.

    ``normalised`` says the frame already is the models' input (``normalise_frame``'s output,
    as ``gsa simulate`` data sets store it): it is then taken as sent, since normalising twice
    would change it. ``cells_m`` (range, cross-range metres) resamples in metres to the
    models' cells ``model_cells_m`` (``resample_metres``), whatever the frame's size; without it, a frame of
    another size needs ``resample`` (in pixels, which is only right when it spans the same
    metres as the models' frames).
    """
    mag = upload.magnitude
    if normalised:
        lo, hi = float(mag.min()), float(mag.max())
        if lo < 0.0 or hi > 1.0:
            raise InputError(
                _loc(upload.name),
                f"normalised=true needs values in [0, 1] (inference.frames.normalise_frame output); "
                f"this frame spans [{lo:.3g}, {hi:.3g}]: send it without normalised=true",
            )
        # normalise_frame maps its 99.5th percentile and everything above it to 1.0, so at least
        # 0.5 % of a normalised frame's pixels are 1.0; a raw frame that merely lies in [0, 1] is not.
        at_top = float(np.mean(mag >= 0.999))
        if at_top < NORMALISED_MIN_TOP_SHARE:
            raise InputError(
                _loc(upload.name),
                f"normalised=true, but only {100 * at_top:.2g} % of the pixels are at 1.0, where "
                "inference.frames.normalise_frame puts 0.5 %: this is a raw frame; send it without normalised=true",
            )
    if cells_m is not None:
        if model_cells_m is None:
            raise ValueError("resampling in metres needs the models' cells")
        mag = resample_metres(mag, cells_m, model_cells_m, size)
    elif mag.shape != (size, size):
        if not resample:
            raise InputError(
                _loc(upload.name),
                f"frame is {mag.shape[0]}x{mag.shape[1]}; the models take {size}x{size}: send range_cell_m and "
                "cross_range_cell_m to resample in metres, or resample=true to resample in pixels",
            )
        if min(mag.shape) < 8 or max(mag.shape) > 8192:
            raise InputError(
                _loc(upload.name), f"frame of {list(mag.shape)} cannot be resampled: 8 to 8192 pixels a side"
            )
        from scipy.ndimage import zoom

        mag = zoom(mag, (size / mag.shape[0], size / mag.shape[1]), order=1)
    if normalised:
        return np.clip(mag, 0.0, 1.0).astype(np.float32)
    return normalise_frame(mag)


def png_bytes(frame: NDArray[np.floating]) -> bytes:
    """Encode a frame in [0, 1] (clipped) as an 8-bit grayscale PNG, written directly and left uncompressed.

    Radar speckle barely compresses (Pillow at level 1 saved 6 % of the bytes) and Pillow took
    2.2 ms a frame here, a third of a request's overhead with two images per estimate; this
    writer takes 0.06 ms. Any PNG reader reads it (deflate's stored blocks; a test reads it back).
    """
    pixels = (np.clip(frame, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    h, w = pixels.shape
    rows = np.zeros((h, w + 1), np.uint8)  # each row starts with its filter type, 0: none
    rows[:, 1:] = pixels

    def chunk(tag: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data))

    header = struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0)  # 8-bit grayscale, no interlace
    return (
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", header)
        + chunk(b"IDAT", zlib.compress(rows.tobytes(), 0))
        + chunk(b"IEND", b"")
    )


def store_blob(data_dir: Path, data: bytes) -> str:
    """Store bytes content-addressed under ``data_dir/images``; return their sha256."""
    digest = hashlib.sha256(data).hexdigest()
    path = blob_path(data_dir, digest)
    if not path.exists():
        private_dir(path.parent)
        tmp = path.with_name(f"{digest}.{os.getpid()}.{threading.get_ident()}.tmp")
        write_private(tmp, data)
        tmp.replace(path)
    return digest


def sweep_blobs(*, session: Any, data_dir: Path, grace_s: float = 0.0) -> int:
    """Remove image files (and half-written ``.tmp`` files) that no estimate refers to; return how many.

    Only files older than ``grace_s`` go, so a host sharing the folder can finish a write in flight.
    """
    import time

    from app import crud

    root = Path(data_dir) / "images"
    if not root.is_dir():
        return 0
    used = crud.blob_digests(session=session)
    cutoff = time.time() - grace_s
    removed = 0
    for path in root.glob("*/*"):
        stale = path.suffix == ".tmp" or (path.suffix == ".png" and path.stem not in used)
        try:
            if stale and path.stat().st_mtime <= cutoff:
                path.unlink()
                removed += 1
        except FileNotFoundError:
            continue
    return removed


def blob_path(data_dir: Path, digest: str) -> Path:
    return Path(data_dir) / "images" / digest[:2] / f"{digest}.png"


def matrix_attitude_json(r: NDArray[np.float64]) -> dict[str, Any]:
    """``attitude_json`` of a rotation matrix, which it keeps as given (not rebuilt from its Euler angles)."""
    out = attitude_json(np.array(euler_from_matrix(r)))
    out["rotation_matrix"] = np.asarray(r).round(12).tolist()
    return out


def attitude_json(angles_deg: NDArray[np.floating]) -> dict[str, Any]:
    z, y, x = (float(a) for a in angles_deg)
    r = rotation_matrix(z, y, x)
    return {
        "euler_zyx_deg": [z, y, x],
        "quaternion_wxyz": list(euler_to_quaternion(z, y, x)),
        "rotation_matrix": r.round(12).tolist(),
    }


def check_frames(*, est: Any, checker: Any, uploads: list[Upload], resample: bool, normalised: bool,
                 cells_m: tuple[float, float] | None, refine: bool = True,
                 search: bool = True) -> tuple[Any, Any, list[Any], dict[str, float]]:  # fmt: skip
    """Prepare uploads, run the models on them as one batch and fit and check each; return frames, models' output,
    checks and the seconds per frame of each stage."""
    import time

    t0 = time.perf_counter()
    model_cells = (checker.radar.range_cell_m, checker.radar.cross_range_cell_m)
    frames = np.stack([prepare(u, est.img_size, resample, normalised, cells_m, model_cells) for u in uploads])
    t_prep = time.perf_counter() - t0
    res = est.estimate(frames)
    t1 = time.perf_counter()
    checks = [checker.check(frames[k], res.enhanced[k], res.angles_deg[k] if checker.networks else None, refine, search)
              for k in range(len(uploads))]  # fmt: skip
    t_fit = time.perf_counter() - t1
    n = len(uploads)
    per_frame = {"preprocess": t_prep / n, **{k: v / n for k, v in res.timings_s.items()}, "fit": t_fit / n}
    return frames, res, checks, per_frame


def checked_json(checked: Any) -> dict[str, Any]:
    """Return an ``inference.trust.Checked`` as the stored result's attitude, quality and alternatives."""
    q = checked.quality
    return {
        "attitude": attitude_json(checked.angles_deg),
        "attitude_network": None if checked.network_deg is None else attitude_json(checked.network_deg),
        "refined": checked.refined,
        "quality": {
            "silhouette_iou": q.silhouette_iou,
            "uncertainty_deg": [b if math.isfinite(b) else None for b in q.uncertainty_deg],
            "trusted": q.trusted,
            "reasons": list(q.reasons),
        },  # fmt: skip
        "alternatives": [
            {
                **attitude_json(np.array(a.angles_deg)),
                "silhouette_iou": round(a.silhouette_iou, 4),
                "fit_gap": round(a.fit_gap, 5),
                "distance_deg": round(a.distance_deg, 2),
            }  # fmt: skip
            for a in checked.alternatives
        ],
    }


def target_track(plan_request: dict[str, Any], epoch: datetime, t0_s: float, t1_s: float) -> tuple[Any, Any, Any]:
    """Return a stored plan's target trajectory over ``[t0_s, t1_s]`` after ``epoch``, its station and Earth frames."""
    from app.schemas import PlanCreate
    from app.services.planning import plan_options, to_orbit, to_station
    from planner.plan import target_trajectory
    from planner.propagation import EarthFrames, as_utc, seconds_between

    req = PlanCreate.model_validate(plan_request)
    target = to_orbit(req.target, "target")
    station = to_station(req.ground_station)
    reading = plan_options(req).reading
    epoch = as_utc(epoch)
    frames = EarthFrames(epoch, t0_s - 3600.0, t1_s + 3600.0)
    if target.tle is None and reading != "mean":
        assert target.elements is not None
        if abs(seconds_between(epoch, target.elements.epoch)) > 60 * 86400:
            raise InputError(["observed_at"], "observed_at is more than 60 days from the target's epoch")
    if target.tle is None and reading == "mean":
        from planner.propagation import SecularJ2Trajectory

        assert target.elements is not None
        return SecularJ2Trajectory(target.elements, epoch), station, frames
    if target.tle is None:
        from planner.propagation import NumericalJ2Trajectory

        assert target.elements is not None
        return NumericalJ2Trajectory.from_elements(target.elements, epoch, t0_s - 1.0, t1_s + 1.0), station, frames
    return target_trajectory(target, epoch, frames, t1_s, reading), station, frames


def frames_at(plan_request: dict[str, Any], observed_at: datetime) -> dict[str, NDArray[np.float64]]:
    """Return the observation, LVLH and J2000 (GCRS) axes at ``observed_at`` for a stored plan's target and station.

    Each is a matrix whose columns are the frame's axes in GCRS (``planner.frames``: the
    observation frame's Y follows the line of sight's rate in the target's LVLH frame).
    """
    return frames_at_times(plan_request, [observed_at])[0]


def frames_at_times(plan_request: dict[str, Any], times: list[datetime]) -> list[dict[str, NDArray[np.float64]]]:
    """``frames_at`` for several moments, from one propagation of the target over their span."""
    from planner.frames import observation_axes, pass_geometry

    t0 = min(times)
    offsets = np.array([(t - t0).total_seconds() for t in times])
    traj, station, frames = target_track(plan_request, t0, 0.0, float(offsets.max()))
    near = np.array([-0.5, 0.0, 0.5])
    geo = pass_geometry(traj, station, frames, (offsets[:, None] + near).ravel())
    out = []
    for k in range(len(times)):
        los = geo.los_lvlh[:, 3 * k : 3 * k + 3]
        lvlh = geo.lvlh[3 * k + 1]
        out.append({
            "observation": lvlh @ observation_axes(los, near)[1],
            "lvlh": lvlh,
            "j2000": np.eye(3),
            "los_lvlh": los[:, 1],
            "los_rate_lvlh": (los[:, 2] - los[:, 0]) / (near[2] - near[0]),
        })  # fmt: skip
    return out


def attitudes_in_frames(
    plan_request: dict[str, Any], observed_at: datetime, angles_deg: NDArray[np.floating]
) -> dict[str, Any]:
    """Return the estimated attitude (body to frame) in the LVLH and J2000 frames too."""
    axes = frames_at(plan_request, observed_at)
    body_to_obs = rotation_matrix(*(float(a) for a in angles_deg))
    body_to_gcrs = axes["observation"] @ body_to_obs
    out: dict[str, Any] = {name: matrix_attitude_json(axes[name].T @ body_to_gcrs) for name in ("lvlh", "j2000")}
    out["observation_axes_in_j2000"] = axes["observation"].round(12).tolist()
    return out
