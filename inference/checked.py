"""A frame's checked answer, the one shape every path returns: the silhouette fit and checks (``inference.trust``)
and the refinement on the image (``inference.reflectivity.serve``)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

Vec = NDArray[np.float64]

# Which fit answered: the networks alone, the silhouette fit, or the image's likelihood under the set's map.
NETWORK, SILHOUETTE, IMAGE = "network", "silhouette", "image"


@dataclass(frozen=True)
class Quality:
    silhouette_iou: float
    uncertainty_deg: tuple[float, float, float]
    trusted: bool
    reasons: list[str]


@dataclass(frozen=True)
class Alternative:
    angles_deg: tuple[float, float, float]
    silhouette_iou: float
    fit_gap: float  # how much lower its soft IoU is than the answer's (negative: it fits better, the prior chose)
    distance_deg: float
    start: str


@dataclass(frozen=True)
class Checked:
    angles_deg: Vec
    network_deg: Vec | None
    refined: bool
    quality: Quality
    alternatives: list[Alternative]
    features: dict[str, float]  # what the checks read (for calibration and the record)
    bound_cov_deg2: Vec | None = None  # the 90 % bounds' covariance (``bound_covariance``), where the fit has one
    refined_on: str = SILHOUETTE  # NETWORK, SILHOUETTE or IMAGE
    image_fit: dict[str, float] | None = None  # the answer's likelihood under the map, where IMAGE answered


@dataclass(frozen=True)
class StillRefinement:
    """A still pass's frames refined together on the image (``inference.reflectivity.serve.ImageRefiner.refine_still``):
    the body turn common to them (3 x 3: each frame's attitude times it), the mean objective per pixel after and at
    the start, and how many frames took part."""

    turn: Vec
    nll_per_pixel: float
    start_nll_per_pixel: float
    frames: int
