"""An operator's own target: OBJ and PLY meshes (or PLY point clouds) read into a ``TargetModel``.

A mesh's facets are sampled twice: densely for the skin (the label is its projection)
and at the scatterer spacing for the scattering centres, each with its face's normal.
Every way a file can be unusable is a ``ModelFileError`` naming the file.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from inference.errors import ModelFileError
from inference.simulation.mesh import Mesh
from inference.simulation.targets import FLAT, ISOTROPIC, TargetModel

Vec = NDArray[np.float64]


def _read_obj(path: Path) -> tuple[Vec, NDArray[np.int64]]:
    verts: list[list[float]] = []
    faces: list[list[int]] = []
    for line in path.read_text(errors="replace").splitlines():
        parts = line.split()
        if not parts:
            continue
        if parts[0] == "v" and len(parts) >= 4:
            verts.append([float(x) for x in parts[1:4]])
        elif parts[0] == "f" and len(parts) >= 4:
            idx = [int(p.split("/")[0]) for p in parts[1:]]
            idx = [i - 1 if i > 0 else len(verts) + i for i in idx]
            faces += [[idx[0], idx[k], idx[k + 1]] for k in range(1, len(idx) - 1)]
    return np.array(verts, float).reshape(-1, 3), np.array(faces, np.int64).reshape(-1, 3)


_PLY_TYPES = {
    "char": "i1",
    "uchar": "u1",
    "short": "i2",
    "ushort": "u2",
    "int": "i4",
    "uint": "u4",
    "float": "f4",
    "double": "f8",
    "int8": "i1",
    "uint8": "u1",
    "int16": "i2",
    "uint16": "u2",
    "int32": "i4",
    "uint32": "u4",
    "float32": "f4",
    "float64": "f8",
}


def _read_ply(path: Path) -> tuple[Vec, NDArray[np.int64]]:
    data = path.read_bytes()
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise ModelFileError(f"{path}: not a PLY file (no 'ply' magic or header end)", field="model")
    header = data[:end].decode("ascii", errors="replace").splitlines()
    body = data[data.index(b"\n", end) + 1 :]
    fmt = next((h.split()[1] for h in header if h.startswith("format")), "ascii")
    elements: list[tuple[str, int, list[tuple[str, ...]]]] = []
    for h in header:
        w = h.split()
        if w[:1] == ["element"]:
            elements.append((w[1], int(w[2]), []))
        elif w[:1] == ["property"] and elements:
            elements[-1][2].append(tuple(w[1:]))
    verts = np.zeros((0, 3))
    faces = np.zeros((0, 3), np.int64)
    if fmt == "ascii":
        tokens = body.decode("ascii", errors="replace").split()
        pos = 0
        for name, count, props in elements:
            if name == "vertex":
                k = len(props)
                arr = np.array(tokens[pos : pos + count * k], float).reshape(count, k)
                names = [p[-1] for p in props]
                verts = arr[:, [names.index("x"), names.index("y"), names.index("z")]]
                pos += count * k
            elif name == "face":
                rows = []
                for _ in range(count):
                    n = int(tokens[pos])
                    idx = [int(t) for t in tokens[pos + 1 : pos + 1 + n]]
                    rows += [[idx[0], idx[j], idx[j + 1]] for j in range(1, n - 1)]
                    pos += n + 1
                faces = np.array(rows, np.int64).reshape(-1, 3)
            else:
                pos += count * len(props)
        return verts, faces
    endian = "<" if "little" in fmt else ">"
    offset = 0
    for name, count, props in elements:
        if name == "vertex":
            dtype = np.dtype([(p[-1], endian + _PLY_TYPES[p[0]]) for p in props])
            arr = np.frombuffer(body, dtype, count, offset)
            verts = np.stack([arr["x"], arr["y"], arr["z"]], axis=1).astype(float)
            offset += dtype.itemsize * count
        elif name == "face" and props and props[0][0] == "list":
            ct, it = np.dtype(endian + _PLY_TYPES[props[0][1]]), np.dtype(endian + _PLY_TYPES[props[0][2]])
            rows = []
            for _ in range(count):
                n = int(np.frombuffer(body, ct, 1, offset)[0])
                offset += ct.itemsize
                poly = np.frombuffer(body, it, n, offset).astype(np.int64).tolist()
                offset += it.itemsize * n
                rows += [[poly[0], poly[j], poly[j + 1]] for j in range(1, n - 1)]
            faces = np.array(rows, np.int64).reshape(-1, 3)
        else:
            raise ModelFileError(f"{path}: binary PLY element {name!r} is not supported", field="model")
    return verts, faces


def sample_mesh(verts: Vec, faces: NDArray[np.int64], spacing: float, seed: int = 0) -> tuple[Vec, Vec]:
    """Sample a triangle mesh's surface uniformly by area: about one point per ``spacing``^2."""
    a, b, c = verts[faces[:, 0]], verts[faces[:, 1]], verts[faces[:, 2]]
    cross = np.cross(b - a, c - a)
    area = 0.5 * np.linalg.norm(cross, axis=1)
    keep = area > 0
    a, b, c, cross, area = a[keep], b[keep], c[keep], cross[keep], area[keep]
    n = max(len(area), int(area.sum() / spacing**2))
    rng = np.random.default_rng(seed)
    tri = rng.choice(len(area), size=n, p=area / area.sum())
    r1, r2 = rng.random(n), rng.random(n)
    s1 = np.sqrt(r1)
    pts = (1 - s1)[:, None] * a[tri] + (s1 * (1 - r2))[:, None] * b[tri] + (s1 * r2)[:, None] * c[tri]
    normals = cross[tri] / np.linalg.norm(cross[tri], axis=1, keepdims=True)
    return pts, normals


def load_model(path: str | Path, scale: float = 1.0, scatterer_spacing_m: float = 0.3) -> TargetModel:
    """Load an OBJ or PLY mesh (or PLY point cloud), in metres times ``scale``, centred on its centroid.

    Mesh facets become FLAT scatterers with their face normals; a point cloud's
    points become ISOTROPIC scatterers. Raises ModelFileError naming the file when it
    is missing, unreadable, of an unknown format or empty.
    """
    p = Path(path)
    if not p.is_file():
        raise ModelFileError(f"model file {p} does not exist", field="model")
    suffix = p.suffix.lower()
    try:
        if suffix == ".obj":
            verts, faces = _read_obj(p)
        elif suffix == ".ply":
            verts, faces = _read_ply(p)
        else:
            raise ModelFileError(f"model file {p}: unknown format {suffix!r}; use .obj or .ply", field="model")
    except (ValueError, IndexError, OSError, UnicodeDecodeError) as exc:
        if isinstance(exc, ModelFileError):
            raise
        raise ModelFileError(f"model file {p} is unreadable: {exc}", field="model") from None
    if len(verts) == 0 or not np.all(np.isfinite(verts)):
        raise ModelFileError(f"model file {p} has no usable vertices", field="model")
    if faces.size and (faces.min() < 0 or faces.max() >= len(verts)):
        raise ModelFileError(f"model file {p} has faces pointing at missing vertices", field="model")
    verts = verts * scale
    if len(faces):
        surface, _ = sample_mesh(verts, faces, 0.08)
        sc, normals = sample_mesh(verts, faces, scatterer_spacing_m, seed=1)
        kinds = np.full(len(sc), FLAT, np.int8)
    else:
        surface = verts
        sc = verts[:: max(1, len(verts) // 4000)]
        normals = np.zeros_like(sc)
        kinds = np.full(len(sc), ISOTROPIC, np.int8)
    centroid = surface.mean(axis=0)
    mesh = Mesh(verts - centroid, faces, np.zeros(len(faces), bool)) if len(faces) else None
    return TargetModel(p.stem, surface - centroid, sc - centroid, normals, kinds, f"loaded from {p.name}", mesh)
