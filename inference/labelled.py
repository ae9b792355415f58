"""Labelled frames: a radar's own frames, each with the attitude a GSA scene's optical observer measured.

The folder format (``gsa labelled add``, ``gsa adapt --frames``, ``gsa simulate --scene`` writes it):
one ``.npz`` per frame, any name, read in name order, holding

* ``image``: 2-D, raw magnitudes or complex, ``[range, cross-range]`` (docs/estimation.md's image
  convention); ``normalised`` (bool, optional) says it already is ``normalise_frame``'s output;
* the label, one of: ``angles_deg`` (z, y, x: body to the frame's observation frame, as every
  answer of the service), or ``quaternion_j2000`` (body to J2000, scalar first) with ``observed_at``
  (ISO 8601 UTC), which a plan's geometry turns into the frame's angles (``resolve``);
* optionally ``scene`` (a name: frames of one scene are never split across training and
  validation; a frame without one is a scene of its own), ``attitude_sigma_deg`` (the optical
  estimate's 1-sigma), ``snr_db``, and ``range_cell_m`` with ``cross_range_cell_m`` (the frame is
  then resampled in metres to the models' cells, as the service does; without them it must
  already be the models' size).

numpy and scipy only. Bad files raise ``DatasetError`` naming the file and the member to fix.
"""

from __future__ import annotations

import hashlib
import math
import zipfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from inference.errors import DatasetError, InferenceError
from inference.frames import normalise_frame, normalised_problem, npy_header, resample_metres

Vec = NDArray[np.float64]

SUFFIX = ".npz"
MAX_SIDE = 4096
MAX_FILES = 100_000
MAX_SIGMA_DEG = 10.0  # an optical attitude less sure than this is no label
COVERAGE_CELL_DEG = 15.0  # the attitude-coverage figure's cells
# A quaternion (body to J2000) and its moment -> the frame's Euler angles (body to its observation frame).
Resolver = Callable[[Vec, datetime, str], tuple[float, float, float]]


@dataclass(frozen=True)
class LabelledFrames:
    """Frames with their labels, stacked: ``frames`` [N, H, W] normalised at the models' size, ``angles_deg`` [N, 3].

    ``scenes``, ``names`` (file names) per frame; ``snr_db`` and ``sigma_deg`` [N] (NaN where not given);
    ``observed_at`` per frame (None where not given).
    """

    frames: NDArray[np.float32]
    angles_deg: Vec
    scenes: tuple[str, ...]
    names: tuple[str, ...]
    snr_db: Vec
    sigma_deg: Vec
    observed_at: tuple[str | None, ...]

    def __len__(self) -> int:
        return len(self.names)

    def subset(self, idx: Sequence[int] | NDArray[np.integer]) -> LabelledFrames:
        k = np.asarray(idx, np.int64)
        return LabelledFrames(
            self.frames[k],
            self.angles_deg[k],
            tuple(self.scenes[i] for i in k),
            tuple(self.names[i] for i in k),
            self.snr_db[k],
            self.sigma_deg[k],
            tuple(self.observed_at[i] for i in k),
        )

    def list_sha256(self) -> str:
        """sha256 of the frames' names, scenes and labels in order: what an adaptation's card records."""
        h = hashlib.sha256()
        for name, scene, a in zip(self.names, self.scenes, self.angles_deg, strict=True):
            h.update(f"{name}\t{scene}\t{a[0]:.6f},{a[1]:.6f},{a[2]:.6f}\n".encode())
        return h.hexdigest()

    def per_scene(self) -> dict[str, int]:
        out: dict[str, int] = {}
        for s in self.scenes:
            out[s] = out.get(s, 0) + 1
        return out


def _bad(path: Path, member: str, why: str) -> DatasetError:
    return DatasetError(f"{path.name}: {member}: {why}", field=member)


SMALL_MEMBER_BYTES = 4096  # a label, a time, a flag: what any of them may hold


def member_array(z: Any, path: Path, member: str, max_bytes: int = SMALL_MEMBER_BYTES) -> NDArray[Any]:
    """One member of an open .npz, its header read first: refused (naming it) when its header promises more than
    ``max_bytes`` or objects, and read no further than the header promises, so neither a header promising terabytes
    nor a zip bomb behind a small header is ever decompressed or allocated in full."""
    name = member + ".npy" if member + ".npy" in z.zip.namelist() else member
    try:
        with z.zip.open(name) as fh:
            shape, dtype = npy_header(fh)
            if dtype.hasobject:
                raise _bad(path, member, "numbers or text, not Python objects")
            need = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
            if need > max_bytes:
                raise _bad(path, member, f"its header promises {need:,} bytes, over the {max_bytes:,} it may hold")
            data = fh.read(need + 1)
    except (ValueError, KeyError, OSError, EOFError, zipfile.BadZipFile) as exc:
        if isinstance(exc, DatasetError):
            raise
        raise _bad(path, member, f"not a readable .npy array ({exc})") from None
    if len(data) != need:
        raise _bad(path, member, f"holds {'more' if len(data) > need else 'less'} data than its header says")
    return np.frombuffer(data, dtype=dtype).reshape(shape)


def _scalar(z: Any, path: Path, member: str, lo: float, hi: float) -> float | None:
    if member not in z.files:
        return None
    arr = member_array(z, path, member)
    if arr.size != 1 or arr.dtype.kind not in "biuf":
        raise _bad(path, member, f"a number, not an array of shape {list(arr.shape)} ({arr.dtype})")
    v = float(arr.reshape(()))
    if not (math.isfinite(v) and lo <= v <= hi):
        raise _bad(path, member, f"{v!r} is outside [{lo:g}, {hi:g}]")
    return v


# Bidirectional controls (they reorder how a name reads, so one scene can pass for another) and their marks.
BIDI_CONTROLS = frozenset("\u061c\u200e\u200f\u202a\u202b\u202c\u202d\u202e\u2066\u2067\u2068\u2069")


def _unprintable(c: str) -> bool:
    """A control character, a lone surrogate (not text: it cannot be encoded) or a bidi control."""
    return ord(c) < 32 or 0x7F <= ord(c) < 0xA0 or 0xD800 <= ord(c) <= 0xDFFF or c in BIDI_CONTROLS


def _text(z: Any, path: Path, member: str) -> str | None:
    if member not in z.files:
        return None
    arr = member_array(z, path, member)
    if arr.size != 1 or arr.dtype.kind not in "US":
        raise _bad(path, member, "a text, as numpy writes a str (np.savez(..., scene='pass-3'))")
    text = str(arr.reshape(()).item())
    text = text.decode() if isinstance(text, bytes) else text
    if not text.strip() or len(text) > 200 or any(_unprintable(c) for c in text):
        raise _bad(path, member, "1 to 200 printable characters (no control, bidi control or lone surrogate)")
    return text.strip()


def parse_time(text: str, path: Path) -> datetime:
    """An ISO 8601 time (a trailing Z or an offset; none means UTC) as an aware UTC datetime."""
    try:
        t = datetime.fromisoformat(text.replace("Z", "+00:00"))
    except ValueError:
        raise _bad(path, "observed_at", f"{text!r} is not an ISO 8601 time (2026-06-01T12:00:00Z)") from None
    return t.replace(tzinfo=UTC) if t.tzinfo is None else t.astimezone(UTC)


def observed_times(sources: Sequence[tuple[str, bytes | Path]]) -> list[datetime]:
    """Every readable file's ``observed_at`` (name and bytes, or name and path), read before the frames so a
    plan's scene can span them; a file that cannot be read is skipped here (``read_frame`` names what is wrong)."""
    import io

    times = []
    for name, source in sources:
        try:
            with np.load(io.BytesIO(source) if isinstance(source, bytes) else source, allow_pickle=False) as z:
                text = _text(z, Path(name), "observed_at")
                if text is not None:
                    times.append(parse_time(text, Path(name)))
        except (OSError, ValueError, EOFError, zipfile.BadZipFile):  # DatasetError too: read_frame names it
            continue
    return times


def check_angles(angles: Any, where: str = "angles_deg") -> tuple[float, float, float]:
    """Euler z, y, x (deg) as the service writes them: 3 finite numbers, z and x within +-180, y within +-90."""
    a = np.asarray(angles, np.float64)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise DatasetError(f"{where}: 3 finite numbers (z, y, x in degrees); got {a.tolist()}", field="angles_deg")
    if abs(a[1]) > 90.0 or abs(a[0]) > 180.0 or abs(a[2]) > 180.0:
        raise DatasetError(
            f"{where}: z and x lie within +-180 deg and y within +-90 deg; got {[round(v, 3) for v in a]}",
            field="angles_deg",
        )
    return float(a[0]), float(a[1]), float(a[2])


def prepare_image(
    image: Any,
    size: int,
    model_cells_m: tuple[float, float] | None,
    cells_m: tuple[float, float] | None = None,
    normalised: bool = False,
    where: str = "image",
) -> NDArray[np.float32]:
    """One frame as the models take it: resampled in metres when its cells are given, normalised unless it is."""
    arr = np.asarray(image)
    if arr.dtype.kind not in "biufc" or arr.ndim != 2 or arr.size == 0:
        raise DatasetError(
            f"{where}: a 2-D array of numbers [range, cross-range]; got shape {list(arr.shape)} ({arr.dtype})",
            field="image",
        )
    if max(arr.shape) > MAX_SIDE:
        raise DatasetError(f"{where}: {list(arr.shape)} is over {MAX_SIDE} pixels a side", field="image")
    mag = np.abs(arr.astype(np.complex128 if arr.dtype.kind == "c" else np.float64))
    if not np.all(np.isfinite(mag)):
        raise DatasetError(f"{where}: holds NaN or infinite values", field="image")
    if normalised and (problem := normalised_problem(mag)) is not None:
        raise DatasetError(f"{where}: normalised {problem}: leave normalised out", field="normalised")
    if cells_m is not None:
        if model_cells_m is None:
            raise ValueError("resampling in metres needs the models' cells")
        try:
            mag = resample_metres(mag, cells_m, model_cells_m, size)
        except InferenceError as exc:
            raise DatasetError(f"{where}: {exc}", field="range_cell_m") from exc
    elif mag.shape != (size, size):
        raise DatasetError(
            f"{where}: the frame is {mag.shape[0]}x{mag.shape[1]}; the models take {size}x{size}: give "
            "range_cell_m and cross_range_cell_m to resample it in metres",
            field="image",
        )
    return np.clip(mag, 0.0, 1.0).astype(np.float32) if normalised else normalise_frame(mag)


@dataclass(frozen=True)
class FrameRead:
    """One labelled frame file, read and checked: the models' input, its label, and what the file said."""

    frame: NDArray[np.float32]
    angles_deg: tuple[float, float, float]
    scene: str
    snr_db: float | None
    sigma_deg: float | None
    observed_at: str | None
    quaternion_j2000: tuple[float, float, float, float] | None = None  # the label as given, where in J2000
    scene_given: bool = True  # False: the file named no scene (the file's stem stands in)


MAX_MEMBER_BYTES = 64 * 1024 * 1024  # a member's declared size, checked before it is read (no zip bombs)


def _open_npz(source: Path | bytes, path: Path) -> Any:
    """np.load of a file or of bytes, every member's declared size checked against ``MAX_MEMBER_BYTES`` first."""
    import io

    try:
        raw: Any = io.BytesIO(source) if isinstance(source, bytes) else source
        with zipfile.ZipFile(raw) as zf:
            big = next((i for i in zf.infolist() if i.file_size > MAX_MEMBER_BYTES), None)
        if big is not None:
            raise _bad(path, big.filename.removesuffix(".npy"), f"over {MAX_MEMBER_BYTES // 2**20} MiB uncompressed")
        return np.load(io.BytesIO(source) if isinstance(source, bytes) else source, allow_pickle=False)
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        if isinstance(exc, DatasetError):
            raise
        raise DatasetError(f"{path.name}: not a readable .npz ({exc})", field="file") from exc


def read_frame(
    path: Path,
    size: int,
    model_cells_m: tuple[float, float] | None = None,
    resolve: Resolver | None = None,
    data: bytes | None = None,
    charge: Callable[[tuple[int, ...], str], None] | None = None,
) -> FrameRead:
    """Read and check one labelled frame file (see the module's text); ``data``: its bytes, when not on disk
    (``path`` then only names it). ``charge(shape, name)`` is told the image's shape from its header before the
    image is read (a request's budget; it raises to refuse)."""
    z = _open_npz(data if data is not None else path, path)
    with z:
        if "image" not in z.files:
            raise _bad(path, "image", f"missing (the file holds {', '.join(sorted(z.files)) or 'nothing'})")
        # The image's header first, always: np.load would allocate whatever it promises.
        try:
            member = "image.npy" if "image.npy" in z.zip.namelist() else "image"
            with z.zip.open(member) as fh:
                shape, _dtype = npy_header(fh)
        except (ValueError, KeyError, zipfile.BadZipFile) as exc:
            raise _bad(path, "image", f"not a readable .npy array ({exc})") from None
        if len(shape) != 2:
            raise _bad(path, "image", f"a 2-D array of numbers [range, cross-range]; got shape {list(shape)}")
        if max(shape) > MAX_SIDE:
            raise _bad(path, "image", f"{list(shape)} is over {MAX_SIDE} pixels a side")
        if charge is not None:
            charge(shape, path.name)
        cells = [_scalar(z, path, m, 1e-4, 100.0) for m in ("range_cell_m", "cross_range_cell_m")]
        if (cells[0] is None) != (cells[1] is None):
            raise _bad(path, "range_cell_m", "give range_cell_m and cross_range_cell_m together (metres)")
        normalised = False
        if "normalised" in z.files:
            flag = member_array(z, path, "normalised")
            if flag.size != 1 or flag.dtype.kind not in "bi":
                raise _bad(path, "normalised", "true or false")
            normalised = bool(flag.reshape(()))
        frame = prepare_image(
            z["image"],
            size,
            model_cells_m,
            (cells[0], cells[1]) if cells[0] is not None and cells[1] is not None else None,
            normalised,
            where=f"{path.name}: image",
        )
        observed = _text(z, path, "observed_at")
        when = parse_time(observed, path) if observed is not None else None
        quat = None
        if "angles_deg" in z.files:
            angles = check_angles(member_array(z, path, "angles_deg"), f"{path.name}: angles_deg")
        elif "quaternion_j2000" in z.files:
            q = np.asarray(member_array(z, path, "quaternion_j2000"), np.float64)
            if q.shape != (4,) or not np.all(np.isfinite(q)):
                raise _bad(path, "quaternion_j2000", f"4 finite numbers (w, x, y, z); got shape {list(q.shape)}")
            norm = float(np.linalg.norm(q))
            if abs(norm - 1.0) > 1e-3:
                raise _bad(path, "quaternion_j2000", f"a rotation's quaternion has unit norm; this one's is {norm:.6g}")
            if when is None:
                raise _bad(path, "observed_at", "a quaternion_j2000 label needs the frame's time, observed_at")
            if resolve is None:
                raise _bad(
                    path,
                    "quaternion_j2000",
                    "a label in J2000 needs the plan whose geometry places the frame: give it (gsa adapt --plan, "
                    "plan_id in the API)",
                )
            angles = check_angles(resolve(q / norm, when, path.name), f"{path.name}: quaternion_j2000")
            quat = (float(q[0] / norm), float(q[1] / norm), float(q[2] / norm), float(q[3] / norm))
        else:
            raise _bad(path, "angles_deg", "no label: give angles_deg, or quaternion_j2000 with observed_at")
        scene = _text(z, path, "scene")
        return FrameRead(
            frame,
            angles,
            scene or path.stem,
            _scalar(z, path, "snr_db", -60.0, 100.0),
            _scalar(z, path, "attitude_sigma_deg", 0.0, MAX_SIGMA_DEG),
            when.isoformat() if when is not None else None,
            quat,
            scene is not None,
        )


def frame_files(folder: str | Path) -> list[Path]:
    """The folder's ``.npz`` files in name order; a missing or empty folder is refused."""
    folder = Path(folder)
    if not folder.is_dir():
        raise DatasetError(f"{folder} is not a folder of labelled frames (one .npz per frame)", field="frames")
    files = sorted(p for p in folder.iterdir() if p.suffix == SUFFIX and p.is_file())
    if not files:
        raise DatasetError(f"{folder} holds no .npz frames", field="frames")
    if len(files) > MAX_FILES:
        raise DatasetError(f"{folder} holds {len(files)} frames; at most {MAX_FILES}", field="frames")
    return files


def read_folder(
    folder: str | Path,
    size: int,
    model_cells_m: tuple[float, float] | None = None,
    resolve: Resolver | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> LabelledFrames:
    """Read every labelled frame of a folder (``frame_files``); the first bad file stops it, named."""
    files = frame_files(folder)
    rows = []
    for k, f in enumerate(files):
        rows.append(read_frame(f, size, model_cells_m, resolve))
        if progress is not None:
            progress(k + 1, len(files))
    return LabelledFrames(
        np.stack([r.frame for r in rows]),
        np.array([r.angles_deg for r in rows], np.float64),
        tuple(r.scene for r in rows),
        tuple(f.name for f in files),
        np.array([np.nan if r.snr_db is None else r.snr_db for r in rows]),
        np.array([np.nan if r.sigma_deg is None else r.sigma_deg for r in rows]),
        tuple(r.observed_at for r in rows),
    )


def write_frame(
    path: str | Path | Any,
    image: Any,
    *,
    angles_deg: Sequence[float] | None = None,
    quaternion_j2000: Sequence[float] | None = None,
    observed_at: datetime | str | None = None,
    scene: str | None = None,
    attitude_sigma_deg: float | None = None,
    snr_db: float | None = None,
    cells_m: tuple[float, float] | None = None,
    normalised: bool = False,
) -> Any:
    """Write one labelled frame in the folder format (the reader's counterpart; at least one label) to a path
    or a file object; return it."""
    if angles_deg is None and quaternion_j2000 is None:
        raise DatasetError("a labelled frame needs angles_deg or quaternion_j2000", field="angles_deg")
    members: dict[str, Any] = {"image": np.asarray(image)}
    if normalised:
        members["normalised"] = np.array(True)
    if angles_deg is not None:
        members["angles_deg"] = np.asarray(angles_deg, np.float64)
    if quaternion_j2000 is not None:
        members["quaternion_j2000"] = np.asarray(quaternion_j2000, np.float64)
    if observed_at is not None:
        members["observed_at"] = np.array(observed_at.isoformat() if isinstance(observed_at, datetime) else observed_at)
    if scene is not None:
        members["scene"] = np.array(scene)
    if attitude_sigma_deg is not None:
        members["attitude_sigma_deg"] = np.array(float(attitude_sigma_deg))
    if snr_db is not None and math.isfinite(snr_db):
        members["snr_db"] = np.array(float(snr_db))
    if cells_m is not None:
        members["range_cell_m"], members["cross_range_cell_m"] = np.array(cells_m[0]), np.array(cells_m[1])
    if not isinstance(path, str | Path):  # a file object (an upload being built in memory)
        np.savez_compressed(path, **members)
        return path
    path = Path(path)
    np.savez_compressed(path, **members)
    return path


def scene_split(
    scenes: Sequence[str], validation_share: float = 0.3, seed: int = 0
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Split frames into training and validation by scene: no scene on both sides.

    Whole scenes (in a seeded random order) go to validation until it holds ``validation_share`` of the
    frames (at least one scene, and at least one left for training). Needs two scenes or more.
    """
    names = sorted(set(scenes))
    if len(names) < 2:
        raise DatasetError(
            f"the frames come from {len(names)} scene(s); splitting by scene needs at least 2 (frames of one "
            "scene are never on both sides of the split): add frames of another scene, or give each frame its "
            "own scene",
            field="scene",
        )
    order = [names[k] for k in np.random.default_rng(seed).permutation(len(names))]
    counts = dict.fromkeys(names, 0)
    for s in scenes:
        counts[s] += 1
    held: set[str] = set()
    total = len(scenes)
    for s in order[:-1]:
        if held and sum(counts[h] for h in held) >= validation_share * total:
            break
        held.add(s)
    mask = np.array([s in held for s in scenes])
    return np.flatnonzero(~mask), np.flatnonzero(mask)


def coverage(angles_deg: Vec, limit_deg: float = 45.0, cell_deg: float = COVERAGE_CELL_DEG) -> float:
    """The share of the networks' attitude cube (each angle within +-``limit_deg``) in cells of ``cell_deg``
    holding at least one labelled frame: how much of what the networks answer the labels teach."""
    a = np.asarray(angles_deg, np.float64).reshape(-1, 3)
    n = max(1, int(round(2 * limit_deg / cell_deg)))
    inside = np.all(np.abs(a) <= limit_deg, axis=1)
    if not np.any(inside):
        return 0.0
    idx = np.clip(np.floor((a[inside] + limit_deg) / (2 * limit_deg) * n).astype(int), 0, n - 1)
    return len({tuple(r) for r in idx}) / n**3


def concatenated(parts: Sequence[LabelledFrames]) -> LabelledFrames:
    """Several folders' frames as one set (names prefixed by their part's index where they would repeat)."""
    if len(parts) == 1:
        return parts[0]
    names = [n for p in parts for n in p.names]
    if len(set(names)) != len(names):
        names = [f"{k}/{n}" for k, p in enumerate(parts) for n in p.names]
    return LabelledFrames(
        np.concatenate([p.frames for p in parts]),
        np.concatenate([p.angles_deg for p in parts]),
        tuple(s for p in parts for s in p.scenes),
        tuple(names),
        np.concatenate([p.snr_db for p in parts]),
        np.concatenate([p.sigma_deg for p in parts]),
        tuple(t for p in parts for t in p.observed_at),
    )


FramesArg = LabelledFrames | str | Path | Sequence[str | Path]


def read_labelled(frames: FramesArg, size: int, cells: tuple[float, float]) -> LabelledFrames:
    """Labelled frames from a folder or several (``read_folder``, at the models' ``size`` and ``cells``), or as given."""
    if isinstance(frames, LabelledFrames):
        return frames
    folders = [frames] if isinstance(frames, str | Path) else list(frames)
    return concatenated([read_folder(f, size, cells) for f in folders])
