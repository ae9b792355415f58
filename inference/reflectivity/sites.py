"""The map's sites: points sampled on the target's skin, each with its normal, area, flat panel and part.

numpy and scipy only. ``sites_of(model, spacing_m)`` samples the target's triangle mesh at about one site per
``spacing_m`` squared (the facets' centroids merged per voxel of ``spacing_m``, never across opposite normals, so the
two faces of a thin wing stay two sites). A target given as a point cloud (no mesh) takes its skin points, every
site two-sided.

Each site knows its **panel**: the facets joined edge to edge whose normals agree within ``PANEL_DEG`` (a flat
plate, a wing face, one strip of a faceted cylinder). A panel's extents along its two in-plane principal axes set
the width of its specular lobe (``inference.reflectivity.model``). Each site also knows its **part**: the connected
piece of the mesh it lies on (a module, a wing), whose specular reflectivity the map learns once for all its panels.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from inference.simulation.mesh import Mesh, bisect
from inference.simulation.targets import TargetModel, surface_normals

Vec = NDArray[np.float64]
Ints = NDArray[np.int64]

PANEL_DEG = 2.0  # neighbouring facets whose normals agree this closely are one flat panel
MIN_PANEL_M = 0.02  # a panel's extent is never taken below this (a sliver's lobe would be a sphere's)


@dataclass(frozen=True)
class Sites:
    """Sites on a target's skin, body frame: ``points``, unit ``normals`` (outward; either way where two-sided),
    ``areas`` (m^2), ``two_sided``; per site its ``panel`` and ``part``; per panel its in-plane axes
    ``panel_axes`` (P, 2, 3), extents ``panel_extent_m`` (P, 2), area ``panel_area_m2`` (P,) and normal
    ``panel_normal`` (P, 3). ``target`` and ``fingerprint`` (a hash of the skin) tie a map to its target."""

    target: str
    points: Vec
    normals: Vec
    areas: Vec
    two_sided: NDArray[np.bool_]
    panel: Ints
    part: Ints
    panel_axes: Vec
    panel_extent_m: Vec
    panel_area_m2: Vec
    panel_normal: Vec
    fingerprint: str

    def __len__(self) -> int:
        return len(self.points)

    @property
    def n_parts(self) -> int:
        return int(self.part.max()) + 1 if len(self.part) else 0


def skin_fingerprint(model: TargetModel) -> str:
    """sha256 of the target's skin (its mesh where it has one, else its surface points), rounded to 0.1 mm."""
    h = hashlib.sha256()
    if model.mesh is not None:
        h.update(np.round(model.mesh.vertices, 4).astype(np.float64).tobytes())
        h.update(np.asarray(model.mesh.faces, np.int64).tobytes())
    else:
        h.update(np.round(np.asarray(model.surface, float), 4).tobytes())
    return h.hexdigest()


def _facet_geometry(mesh: Mesh) -> tuple[Vec, Vec, Vec]:
    """Each facet's centroid, unit normal (from its winding) and area."""
    t = mesh.triangles
    cross = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    norm = np.linalg.norm(cross, axis=1)
    normals = cross / np.maximum(norm, 1e-300)[:, None]
    return t.mean(axis=1), normals, 0.5 * norm


def _edge_pairs(faces: Ints) -> Ints:
    """Pairs of facets (E, 2) that share an edge."""
    f = np.asarray(faces, np.int64)
    edges = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    owner = np.tile(np.arange(len(f)), 3)
    key = np.sort(edges, axis=1)
    order = np.lexsort((key[:, 1], key[:, 0]))
    key, owner = key[order], owner[order]
    same = np.all(key[1:] == key[:-1], axis=1)
    return np.stack([owner[:-1][same], owner[1:][same]], axis=1)


def _components(n: int, pairs: Ints) -> Ints:
    """Connected components of ``n`` nodes joined by ``pairs``."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    graph = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    return np.asarray(connected_components(graph, directed=False)[1], np.int64)


def _parts(mesh: Mesh) -> Ints:
    """Each facet's part: the connected piece of the mesh (facets sharing a vertex)."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    f = np.asarray(mesh.faces, np.int64)
    rows = np.repeat(np.arange(len(f)), 3)
    incidence = sp.csr_matrix((np.ones(f.size), (rows, f.ravel())), shape=(len(f), len(mesh.vertices)))
    return np.asarray(connected_components(incidence @ incidence.T, directed=False)[1], np.int64)


def _panels(triangles: Vec, normals: Vec, areas: Vec, faces: Ints) -> tuple[Ints, Vec, Vec, Vec, Vec]:
    """Flat panels: facets joined across an edge where their normals agree within ``PANEL_DEG``.

    Returns each facet's panel, and per panel its in-plane principal axes (P, 2, 3), extents (P, 2) (the side of the
    rectangle with the same second moments, sqrt(12 var), at least ``MIN_PANEL_M``), area and normal."""
    pairs = _edge_pairs(faces)
    flat = np.einsum("ij,ij->i", normals[pairs[:, 0]], normals[pairs[:, 1]]) >= math.cos(math.radians(PANEL_DEG))
    panel = _components(len(faces), pairs[flat])
    n = int(panel.max()) + 1
    area = np.asarray(np.bincount(panel, areas, n), float)
    normal = np.asarray(np.stack([np.bincount(panel, areas * normals[:, i], n) for i in range(3)], axis=1), float)
    normal /= np.maximum(np.linalg.norm(normal, axis=1), 1e-300)[:, None]
    centroids = triangles.mean(axis=1)
    centre = np.stack([np.bincount(panel, areas * centroids[:, i], n) for i in range(3)], axis=1) / area[:, None]
    # Each triangle's exact second moment about the panel's centre: A/12 (sum v v^T + s s^T), s the corners' sum.
    rel = triangles - centre[panel][:, None, :]
    total = rel.sum(axis=1)
    moment = (np.einsum("nki,nkj->nij", rel, rel) + np.einsum("ni,nj->nij", total, total)) * (areas / 12.0)[
        :, None, None
    ]
    cov = np.stack([np.bincount(panel, moment.reshape(-1, 9)[:, i], n) for i in range(9)], axis=1).reshape(n, 3, 3)
    cov = np.asarray(cov, float) / area[:, None, None]
    # In-plane axes: the covariance projected on the panel's plane, so a lone facet still gets two axes.
    proj = np.eye(3)[None] - np.einsum("ni,nj->nij", normal, normal)
    vals, vecs = np.linalg.eigh(proj @ cov @ proj)
    axes = np.moveaxis(vecs[:, :, 1:], 2, 1)  # the two largest: (P, 2, 3)
    extent = np.sqrt(12.0 * np.maximum(vals[:, 1:], 0.0))  # the rectangle with these moments
    return panel, axes, np.maximum(extent, MIN_PANEL_M), area, normal


def sites_of(model: TargetModel, spacing_m: float = 0.1) -> Sites:
    """Sample the target's skin at about one site per ``spacing_m`` squared (see the module's text)."""
    if not spacing_m > 0:
        raise ValueError(f"spacing_m {spacing_m} must be positive")
    if model.mesh is None:
        pts = np.asarray(model.surface, float)
        nrm = surface_normals(pts)
        cells = np.floor(pts / spacing_m).astype(np.int64)
        _, keep = np.unique(cells, axis=0, return_index=True)
        keep = np.sort(keep)
        k = len(keep)
        area = np.full(k, spacing_m**2)
        axes = np.stack([np.linalg.svd(n[None])[2][1:] for n in nrm[keep]])
        return Sites(
            model.name,
            pts[keep],
            nrm[keep],
            area,
            np.ones(k, bool),
            np.arange(k),
            np.zeros(k, np.int64),
            axes,
            np.full((k, 2), spacing_m),
            area.copy(),
            nrm[keep],
            skin_fingerprint(model),
        )
    mesh = model.mesh
    _, facet_normals, facet_areas = _facet_geometry(mesh)
    panel_of, axes, extent, panel_area, panel_normal = _panels(mesh.triangles, facet_normals, facet_areas, mesh.faces)
    part_of = _parts(mesh)
    # Facets halved until no edge exceeds the spacing (a wing may be two triangles), then merged per voxel and per
    # normal direction class (never the two faces of a thin sheet), within one panel.
    tris, parent = bisect(mesh.triangles, spacing_m)
    centroids = tris.mean(axis=1)
    areas = 0.5 * np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=1)
    normals = facet_normals[parent]
    panel, part = panel_of[parent], part_of[parent]
    cells = np.floor(centroids / spacing_m).astype(np.int64)
    dominant = np.argmax(np.abs(normals), axis=1)
    sign = np.take_along_axis(normals, dominant[:, None], axis=1)[:, 0] > 0
    key = np.column_stack([cells, 2 * dominant + sign, panel])
    _, inv = np.unique(key, axis=0, return_inverse=True)
    inv = inv.ravel()
    n = int(inv.max()) + 1
    area = np.asarray(np.bincount(inv, areas, n), float)
    pts = np.stack([np.bincount(inv, areas * centroids[:, i], n) for i in range(3)], axis=1) / area[:, None]
    nrm = np.asarray(np.stack([np.bincount(inv, areas * normals[:, i], n) for i in range(3)], axis=1), float)
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1), 1e-300)[:, None]
    first = np.zeros(n, np.int64)
    first[inv[::-1]] = np.arange(len(inv))[::-1]  # one facet of each site, for its panel, part and sidedness
    return Sites(
        model.name,
        pts,
        nrm,
        area,
        np.asarray(mesh.two_sided, bool)[parent][first],
        panel[first],
        part[first],
        axes,
        extent,
        panel_area,
        panel_normal,
        skin_fingerprint(model),
    )
