"""Frame images: an 8-bit PNG writer, and the content-addressed store the estimates' images live in."""

from __future__ import annotations

import hashlib
import os
import struct
import threading
import zlib
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from app.core.security import private_dir, write_private

if TYPE_CHECKING:
    from sqlalchemy.orm import Session


def png_bytes(frame: NDArray[np.floating]) -> bytes:
    """Encode a frame in [0, 1] (clipped) as an 8-bit grayscale PNG, written directly and left uncompressed.

    Radar speckle barely compresses, and a general encoder costs a good share of a request;
    deflate's stored blocks cost almost nothing and any PNG reader reads them (design/measurements.md,
    "PNG writer"; a test reads it back).
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


def sweep_blobs(*, session: Session, data_dir: Path, grace_s: float = 0.0) -> int:
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


def png_frame(data: bytes) -> NDArray[np.float64]:
    """Read back a frame ``png_bytes`` wrote (8-bit grayscale, unfiltered rows): [H, W] in [0, 1]."""
    w, h = struct.unpack(">II", data[16:24])
    pos, idat = 8, b""
    while pos < len(data):
        (length,) = struct.unpack(">I", data[pos : pos + 4])
        if data[pos + 4 : pos + 8] == b"IDAT":
            idat += data[pos + 8 : pos + 8 + length]
        pos += 12 + length
    rows = np.frombuffer(zlib.decompress(idat), np.uint8).reshape(h, w + 1)
    return np.asarray(rows[:, 1:], np.float64) / 255.0


def blob_path(data_dir: Path, digest: str) -> Path:
    return Path(data_dir) / "images" / digest[:2] / f"{digest}.png"


def outline_png(occupancy: NDArray[np.bool_]) -> bytes:
    """The edge of a silhouette (its pixels with a neighbour outside it) as an 8-bit PNG: 255 on the edge, 0 elsewhere."""
    from scipy.ndimage import binary_erosion

    edge = occupancy & ~binary_erosion(occupancy)
    return png_bytes(edge.astype(np.float64))
