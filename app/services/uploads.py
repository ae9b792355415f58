"""Uploaded bytes to frames: .npy, .npz stacks and images decoded with their limits, and the
normalisation policy (resampling to the radar's cells, normalising unless the file says it is)."""

from __future__ import annotations

import hashlib
import io
import zipfile
import zlib
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.errors import InputError, TooLarge
from inference.errors import InferenceError
from inference.frames import normalise_frame, normalised_problem, npy_header
from inference.frames import resample_metres as _resample_metres

MAX_NPZ_MEMBER_BYTES = 64 * 1024 * 1024  # decompressed; refuses zip bombs before reading them


@dataclass(frozen=True, slots=True)
class Upload:
    """One decoded frame: the magnitude image and what it came from."""

    name: str
    sha256: str
    shape: tuple[int, ...]
    dtype: str
    magnitude: NDArray[np.float64]
    normalised: bool = False  # the file says so: a ``gsa simulate`` shard holds the models' input already


def _loc(name: str) -> list[str | int]:
    return ["file", name]


DEFAULT_MAX_SIDE = 4096
# What marks a `gsa simulate` shard (inference.simulation.dataset): normalised frames beside their truths.
SHARD_MEMBERS = {"image.npy", "label.npy", "angles_deg.npy"}


@dataclass(slots=True)
class DecodeBudget:
    """What one request may decode, charged from each file's header before its pixels are read: frames, and
    bytes counted as the float64 magnitudes the service holds (8 bytes a pixel, whatever the file's dtype).

    A 16 kB PNG of 4096 x 4096 is 128 MiB decoded; without a budget every file of a request was decoded before
    the frame limit was checked.
    """

    max_frames: int
    max_bytes: int
    field: str = "files"  # the form field the frames came in
    frames: int = 0
    bytes: int = 0

    @classmethod
    def of(cls, settings: Any, field: str = "files") -> DecodeBudget:
        """The budget of one request under the service's settings (GSA_MAX_BATCH_FRAMES, GSA_MAX_DECODED_MB)."""
        return cls(int(settings.max_batch_frames), int(settings.max_decoded_mb) * 2**20, field)

    def charge(self, shape: tuple[int, ...], name: str) -> None:
        """Count an array of ``shape`` (a frame, or a stack [N, H, W]) of file ``name``; refuse it over the budget."""
        self.frames += int(shape[0]) if len(shape) == 3 else 1
        self.bytes += 8 * int(np.prod(shape, dtype=np.int64))
        if self.frames > self.max_frames:
            raise InputError(
                [self.field],
                f"the request holds over {self.max_frames} frames (the limit, GSA_MAX_BATCH_FRAMES) by {name!r}; "
                "send the rest in another request",
            )
        if self.bytes > self.max_bytes:
            raise TooLarge(
                f"decoded, the request's frames take over {self.max_bytes // 2**20} MiB by {name!r} (8 bytes "
                "a pixel; the limit is GSA_MAX_DECODED_MB): send fewer or smaller frames",
            )


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
    if arr.dtype.kind == "c":
        mag = np.abs(arr).astype(np.float64, copy=False)
    else:  # one float64 copy, its magnitude taken in place (a 4096 x 4096 frame is 128 MiB of it)
        mag = arr.astype(np.float64)
        np.abs(mag, out=mag)
    if not np.all(np.isfinite(mag)):
        raise InputError(_loc(name), "the frame contains NaN or infinite values")
    if not np.any(mag):
        raise InputError(_loc(name), "the frame is all zero: there is no echo to estimate an attitude from")
    if float(mag.max()) == float(mag.min()):
        raise InputError(_loc(name), "the frame is constant: there is no structure to estimate an attitude from")
    return np.asarray(mag, np.float64)


def _npy(data: bytes, name: str, max_side: int = DEFAULT_MAX_SIDE, budget: DecodeBudget | None = None) -> NDArray[Any]:
    """Read a .npy array after checking its header against the bytes that follow and the request's budget
    (numpy allocates what the header promises first)."""
    buf = io.BytesIO(data)
    try:
        shape, dtype = npy_header(buf)
    except ValueError as exc:
        raise InputError(_loc(name), f"not a readable .npy array: {exc}") from None
    if dtype.hasobject:
        raise InputError(_loc(name), f"unsupported dtype {dtype}; send real or complex numbers")
    if len(shape) > 3 or any(int(d) < 0 for d in shape):
        raise InputError(_loc(name), f"a frame must be a 2-D array (or a 3-D stack); this one has shape {list(shape)}")
    _check_side(shape, name, max_side)
    need = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
    if need != len(data) - buf.tell():
        raise InputError(
            _loc(name),
            f"the .npy header promises {need} bytes of {dtype} {list(shape)} but {len(data) - buf.tell()} follow",
        )
    if budget is not None:
        budget.charge(shape, name)
    try:
        buf.seek(0)
        return np.load(buf, allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:
        raise InputError(_loc(name), f"not a readable .npy array: {exc}") from None


def _npz_arrays(
    data: bytes, name: str, max_side: int = DEFAULT_MAX_SIDE, budget: DecodeBudget | None = None
) -> tuple[list[tuple[str, NDArray[Any]]], bool]:
    """The archive's arrays by member name, checked against the limits, and whether it is a ``gsa simulate``
    shard (then its frames alone)."""
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
            shard = SHARD_MEMBERS <= {m.filename for m in members}
            if shard:  # a gsa simulate shard: its frames, not its labels and truths
                members = [m for m in members if m.filename == "image.npy"]
            if budget is not None:  # every member's header against the budget before any member is read
                for m in members:
                    with zf.open(m) as fh:
                        try:
                            shape, _dtype = npy_header(fh)
                        except ValueError as exc:
                            raise InputError(_loc(name), f"{m.filename}: not a readable .npy array: {exc}") from None
                    _check_side(shape, name, max_side)
                    budget.charge(shape, name)
            return [(m.filename.removesuffix(".npy"), _npy(zf.read(m), name, max_side)) for m in members], shard
    except (
        zipfile.BadZipFile,
        zipfile.LargeZipFile,
        NotImplementedError,
        EOFError,
        OSError,
        RuntimeError,
        zlib.error,
    ) as exc:
        raise InputError(_loc(name), f"not a readable .npz archive: {exc}") from None


def _image(
    data: bytes, name: str, max_side: int = DEFAULT_MAX_SIDE, budget: DecodeBudget | None = None
) -> NDArray[Any]:
    from PIL import Image, UnidentifiedImageError

    try:
        img = Image.open(io.BytesIO(data))
        _check_side((img.size[1], img.size[0]), name, max_side)  # before decoding a single pixel
        if budget is not None:
            budget.charge((img.size[1], img.size[0]), name)
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


def declared_shapes(data: bytes, name: str, max_side: int = DEFAULT_MAX_SIDE) -> list[tuple[int, ...]]:
    """The shapes of the arrays a file holds, from its headers alone (nothing decoded): what a request's budget is
    charged with before any of its files is decoded. A file whose headers cannot be read gives none here;
    ``decode`` then says what is wrong with it."""
    head = data[:8]
    try:
        if head.startswith(b"\x93NUMPY"):
            return [npy_header(io.BytesIO(data))[0]]
        if head.startswith(b"PK"):
            with zipfile.ZipFile(io.BytesIO(data)) as zf:
                members = zf.infolist()
                if len(members) > 4096:
                    return []  # decode refuses it by its count
                if SHARD_MEMBERS <= {m.filename for m in members}:
                    members = [m for m in members if m.filename == "image.npy"]
                shapes = []
                for m in members:
                    with zf.open(m) as fh:
                        shapes.append(npy_header(fh)[0])
                return shapes
        if head.startswith(b"\x89PNG") or head[:4] in (b"II*\x00", b"MM\x00*"):
            from PIL import Image

            with Image.open(io.BytesIO(data)) as img:
                return [(int(img.size[1]), int(img.size[0]))]
    except (ValueError, OSError, EOFError, zipfile.BadZipFile, zipfile.LargeZipFile, NotImplementedError, zlib.error):
        return []
    except Exception as exc:  # PIL's own refusals (UnidentifiedImageError is an OSError; DecompressionBombError not)
        if type(exc).__name__ == "DecompressionBombError":
            return []
        raise
    return []


def charge_headers(data: bytes, name: str, budget: DecodeBudget, max_side: int = DEFAULT_MAX_SIDE) -> None:
    """Charge ``budget`` with the file's frames and decoded size from its headers, before anything is decoded."""
    for shape in declared_shapes(data, name, max_side):
        _check_side(shape, name, max_side)
        budget.charge(shape, name)


def decode(
    data: bytes,
    name: str,
    allow_stack: bool = True,
    max_side: int = DEFAULT_MAX_SIDE,
    budget: DecodeBudget | None = None,
) -> list[Upload]:
    """Decode an upload (.npy, .npz, .png, .tif/.tiff) into frames; with ``allow_stack``, arrays [N, H, W] too.

    ``budget``: the request's frames and decoded bytes so far, charged from each file's header before its pixels
    are decoded (several files of one request share it)."""
    if not data:
        raise InputError(_loc(name), "the file is empty")
    digest = hashlib.sha256(data).hexdigest()
    head = data[:8]
    shard = False
    if head.startswith(b"\x93NUMPY"):
        arrays = [(name, _npy(data, name, max_side, budget))]
    elif head.startswith(b"PK"):
        arrays, shard = _npz_arrays(data, name, max_side, budget)
    elif head.startswith(b"\x89PNG") or head[:4] in (b"II*\x00", b"MM\x00*"):
        arrays = [(name, _image(data, name, max_side, budget))]
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
            out.append(Upload(frame_name, digest, tuple(frame.shape), str(arr.dtype), _check_array(frame, name), shard))
    return out


def resample_metres(
    mag: NDArray[np.float64], cells_m: tuple[float, float], model_cells_m: tuple[float, float], size: int
) -> NDArray[np.float64]:
    """``inference.frames.resample_metres``, its refusal as the API's error."""
    try:
        return _resample_metres(mag, cells_m, model_cells_m, size)
    except InferenceError as exc:
        raise InputError([exc.field or "range_cell_m"], str(exc)) from exc


def prepare(
    upload: Upload,
    size: int,
    resample: bool,
    normalised: bool = False,
    cells_m: tuple[float, float] | None = None,
    model_cells_m: tuple[float, float] | None = None,
) -> NDArray[np.float32]:
    """Return the normalised frame the models take: the training normalisation, resampled if asked.

    ``normalised`` says the frame already is the models' input (``normalise_frame``'s output,
    as ``gsa simulate`` data sets store it): it is then taken as sent, since normalising twice
    would change it. ``cells_m`` (range, cross-range metres) resamples in metres to the
    models' cells ``model_cells_m`` (``resample_metres``), whatever the frame's size; without it, a frame of
    another size needs ``resample`` (in pixels, which is only right when it spans the same
    metres as the models' frames). A frame whose file says it is normalised (``upload.normalised``:
    a ``gsa simulate`` shard) is taken as sent too.
    """
    mag = upload.magnitude
    normalised = normalised or upload.normalised
    if normalised and (problem := normalised_problem(mag)) is not None:
        raise InputError(_loc(upload.name), f"normalised=true {problem}: send it without normalised=true")
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
