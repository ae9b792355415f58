"""Files every part of inference/ writes and reads: hashing, checked JSON, atomic writes.

Standard library only, so the simulator, training and the runtime can all import it.
"""

from __future__ import annotations

import hashlib
import json
import os
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

from inference.errors import InferenceError


def sha256_file(path: str | Path) -> str:
    """The file's sha256, read in 1 MiB chunks."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def checked_file(path: Path, sha256: str, what: str) -> Path:
    """``path`` where it is there with this sha256; else ModelFileError (field ``model``) naming it as ``what``."""
    from inference.errors import ModelFileError

    if not path.is_file():
        raise ModelFileError(f"{what} {path} is missing", field="model")
    if sha256_file(path) != sha256:
        raise ModelFileError(
            f"{what} {path} does not match the sha256 in its card (truncated or altered)", field="model"
        )
    return path


def _temporary(path: Path) -> Path:
    """A sibling name no other writer (process or thread) uses at the same time."""
    return path.with_name(f"{path.name}.{os.getpid()}.{threading.get_ident()}.tmp")


def write_atomic(path: str | Path, write: Callable[[Path], Any]) -> None:
    """Call ``write(tmp)`` on a sibling file, then rename it over ``path``: a reader (or a cut-off
    run) sees the old file or the new one, never half of one."""
    target = Path(path)
    tmp = _temporary(target)
    try:
        write(tmp)
        tmp.replace(target)
    finally:
        tmp.unlink(missing_ok=True)


def write_json(path: str | Path, obj: Any) -> None:
    """Write ``obj`` as indented JSON, atomically."""
    write_atomic(path, lambda tmp: tmp.write_text(json.dumps(obj, indent=2) + "\n"))


def read_json(path: str | Path, error: type[InferenceError] = InferenceError, field: str | None = None) -> Any:
    """Read a JSON file; a missing or unreadable one raises ``error`` naming the file (and ``field``)."""
    p = Path(path)
    try:
        return json.loads(p.read_text())
    except FileNotFoundError:
        raise error(f"{p} is missing", field=field) from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise error(f"{p} is not readable JSON: {exc}", field=field) from None
