"""The scene the radar images: which scatterers it sees and how bright, the label, the scattering variety, ``simulate``.

A scatterer's echo depends on its kind and on the angle between its outward normal and
the line of sight (``scatterer_amplitudes``); self-shadowing hides those the hull
covers (``visible``). The label is the target's exact projection on the image plane
(``label_mask``). ``Scattering`` holds the options that vary how the target turns into
an image (DESIGN.md section 3 and docs/networks.md's simulator section); ``simulate`` joins
them with ``inference.simulation.radar``'s echo and image formation into one frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from inference.errors import ModelFileError, RadarError
from inference.rotations import rotation_matrix
from inference.simulation.mesh import Mesh, checked_mesh
from inference.simulation.po import POOptions, po_echo, po_sources, prepared
from inference.simulation.radar import (
    Imager,
    Radar,
    add_noise,
    polar_echo,
    projection_matrix,
    refuse_unusable,
    window_1d,
)
from inference.simulation.targets import CURVED, EDGE, FLAT, ISOTROPIC, TargetModel

Vec = NDArray[np.float64]


def visible(
    points_obs: Vec, normals_obs: Vec, kinds: NDArray[np.int8], los: Vec, cell_m: float = 0.35
) -> NDArray[np.bool_]:
    """Return which scatterers the radar sees: facing it, and not hidden behind nearer parts (z-buffer).

    Flat plates are two-sided; curved skin and edges must face the radar. The
    z-buffer bins points on the plane across the line of sight into ``cell_m`` cells
    and keeps, in each, those within one cell of the nearest.
    """
    facing = normals_obs @ los
    front = np.where((kinds == FLAT) | (kinds == ISOTROPIC), True, facing > -0.05)
    depth = points_obs @ los  # larger is nearer the radar
    basis = np.linalg.svd(los.reshape(1, 3))[2][1:]  # two axes across the line of sight
    across = points_obs @ basis.T
    cells = np.floor(across / cell_m).astype(np.int64)
    cells -= cells.min(axis=0)
    key = cells[:, 0] * (cells[:, 1].max() + 1) + cells[:, 1]
    nearest = np.full(key.max() + 1, -np.inf)
    np.maximum.at(nearest, key[front], depth[front])
    return front & (depth >= nearest[key] - cell_m)


def expected_magnitude(
    normals_obs: Vec,
    kinds: NDArray[np.int8],
    los: Vec,
    lobe_scale: float = 1.0,
    edge_gain: float = 1.0,
    dense: bool = False,
) -> Vec:
    """Return each scatterer's aspect-dependent magnitude before the per-frame jitter (``scatterer_amplitudes``).

    FLAT facets flash when their normal meets the line of sight (Gaussian lobe of
    2 deg) over a weak diffuse floor; CURVED skin is bright along its specular line
    (lobe 6 deg); EDGE points are weak and steady; ISOTROPIC points are all equal.
    ``dense`` gives all of them the curved skin's law.
    """
    cos_t = np.abs(np.clip(normals_obs @ los, -1.0, 1.0))
    angle = np.arccos(cos_t)
    if dense:
        return np.asarray(0.25 + 1.5 * np.exp(-((angle / math.radians(6.0 * lobe_scale)) ** 2)))
    mag = np.empty(len(kinds))
    flat = kinds == FLAT
    curved = kinds == CURVED
    mag[flat] = 0.15 + 3.0 * np.exp(-((angle[flat] / math.radians(2.0 * lobe_scale)) ** 2))
    mag[curved] = 0.25 + 1.5 * np.exp(-((angle[curved] / math.radians(6.0 * lobe_scale)) ** 2))
    mag[kinds == EDGE] = 0.5 * edge_gain
    mag[kinds == ISOTROPIC] = 1.0
    return mag


def scatterer_amplitudes(
    normals_obs: Vec,
    kinds: NDArray[np.int8],
    los: Vec,
    rng: np.random.Generator,
    lobe_scale: float = 1.0,
    edge_gain: float = 1.0,
    dense: bool = False,
) -> NDArray[np.complex128]:
    """Return complex amplitudes: ``expected_magnitude``, seeded log-normal jitter and a random sub-cell phase."""
    mag = expected_magnitude(normals_obs, kinds, los, lobe_scale, edge_gain, dense)
    mag = mag * rng.lognormal(0.0, 0.25, len(kinds))
    return mag * np.exp(2j * np.pi * rng.random(len(kinds)))


def label_mask(imager: Imager, surface_obs: Vec) -> NDArray[np.bool_]:
    """Return the theoretical binary projection: surface points through A onto the image grid (paper eq. 10)."""
    from scipy.ndimage import binary_closing

    radar = imager.radar
    u, v = imager.pixel_coordinates(surface_obs)
    iu, iv = np.rint(u).astype(np.int64), np.rint(v).astype(np.int64)
    ok = (iu >= 0) & (iu < radar.n_range) & (iv >= 0) & (iv < radar.n_azimuth)
    mask = np.zeros((radar.n_range, radar.n_azimuth), bool)
    mask[iu[ok], iv[ok]] = True
    return np.asarray(binary_closing(mask, iterations=1) | mask)


def mask_iou(a: NDArray[np.bool_], b: NDArray[np.bool_]) -> Vec:
    """Intersection over union of binary masks [..., H, W], one per leading index (0 where both are empty)."""
    inter = np.count_nonzero(a & b, axis=(-2, -1))
    union = np.count_nonzero(a | b, axis=(-2, -1))
    return np.asarray(inter / np.maximum(union, 1), np.float64)


@dataclass(frozen=True, slots=True)
class Frame:
    """One simulated frame and its truth."""

    image: NDArray[np.complex128]
    label: NDArray[np.bool_]
    angles_deg: tuple[float, float, float]
    snr_db: float | None


def check_fits(model: TargetModel, radar: Radar) -> None:
    """Raise ModelFileError when some attitude could put the model outside the frame (no silent aliasing)."""
    half = min(radar.extent_m) / 2.0
    if model.radius_m > half:
        raise ModelFileError(
            f"model {model.name!r} reaches {model.radius_m:.1f} m from its centre but the frame is only "
            f"{2 * half:.1f} m across: scale it down or raise n_range/n_azimuth",
            field="model",
        )


WINDOWS = ("taylor", "hamming", "none")


IMAGING = ("polar", "range-doppler")


SCATTERERS = ("lattice", "dense")


PHYSICS = ("centres", "po")
# The options that belong to one physics, at their defaults (what the other physics must leave them at).
CENTRES_ONLY: dict[str, Any] = {"scatterers": "lattice", "edge_gain": 1.0, "lobe_scale": 1.0, "dominant": 0}
PO_ONLY: dict[str, Any] = {"bounces": 1, "roughness": 0.0, "facet_m": 0.2}


@dataclass(frozen=True, slots=True)
class Scattering:
    """How the simulator turns the target into an image; the defaults are what every data set so far used.

    * ``scatterers``: ``lattice``, the model's scattering centres (0.3 m apart); or ``dense``,
      the skin itself (0.08 m apart, jittered by up to 4 cm per frame), several points per
      resolution cell, all with the same aspect law: fully developed speckle, no lattice.
    * ``edge_gain``: factor on rim and edge returns (0: none; 1: 27 % of the image energy).
    * ``lobe_scale``: factor on the specular lobe widths (plates 2 deg, curved skin 6 deg).
    * ``window``: ``taylor`` (Radar.window_sidelobe_db), ``hamming`` or ``none``.
    * ``imaging``: ``polar``, the exact polar-format image; ``range-doppler``, the 2-D FFT of
      the polar samples without reformatting (range migration smears the far parts).
    * ``dominant``: that many point-like returns (dihedrals, ports) at random points of the
      visible skin, each as bright as the brightest scatterer.
    * ``phase_error_rad``: a residual phase error across the aperture (imperfect motion
      compensation), a random quadratic-plus-cubic curve peaking at this value.
    * ``scale_error``: range and cross-range scale errors drawn in +-this (an uncertain
      rotation rate scales cross-range); the label keeps the true geometry.
    * ``blur_px``: Gaussian blur (sigma, pixels) of the magnitude image (defocus).
    * ``physics``: ``centres``, the scattering-centre heuristic above; or ``po``, physical optics on
      the target's facets (``inference.simulation.po``: closed-form facet integrals, ray-traced
      shadowing), which takes ``bounces`` (1, or 2-3 for shooting and bouncing rays), ``roughness``
      (Lambert's gamma of a diffuse term per facet, 0-1) and ``facet_m`` (facet size, 0.05-0.5 m)
      instead of ``scatterers``, ``edge_gain``, ``lobe_scale`` and ``dominant``.
    """

    scatterers: str = "lattice"
    edge_gain: float = 1.0
    lobe_scale: float = 1.0
    window: str = "taylor"
    imaging: str = "polar"
    dominant: int = 0
    phase_error_rad: float = 0.0
    scale_error: float = 0.0
    blur_px: float = 0.0
    physics: str = "centres"
    bounces: int = 1
    roughness: float = 0.0
    facet_m: float = 0.2

    def __post_init__(self) -> None:
        checks = (
            ("physics", self.physics in PHYSICS),
            ("bounces", isinstance(self.bounces, int) and 1 <= self.bounces <= 3),
            ("roughness", 0.0 <= self.roughness <= 1.0),
            ("facet_m", 0.05 <= self.facet_m <= 0.5),
            ("scatterers", self.scatterers in SCATTERERS),
            ("edge_gain", 0.0 <= self.edge_gain <= 10.0),
            ("lobe_scale", 0.1 <= self.lobe_scale <= 10.0),
            ("window", self.window in WINDOWS),
            ("imaging", self.imaging in IMAGING),
            ("dominant", 0 <= self.dominant <= 100),
            ("phase_error_rad", 0.0 <= self.phase_error_rad <= 2 * math.pi),
            ("scale_error", 0.0 <= self.scale_error <= 0.2),
            ("blur_px", 0.0 <= self.blur_px <= 10.0),
        )
        refuse_unusable(self, checks)
        other, wrong = ("centres", CENTRES_ONLY) if self.physics == "po" else ("po", PO_ONLY)
        for name, default in wrong.items():
            if getattr(self, name) != default:
                raise RadarError(
                    f"{name} does not apply to physics {self.physics!r} (it belongs to the {other!r} physics)",
                    field=name,
                )


DEFAULT_SCATTERING = Scattering()


# The simulator variants of the robustness benchmark (bench/trust.py): none was used in training.
VARIANTS = {
    "dense speckle scatterers": Scattering(scatterers="dense"),
    "no edge scatterers": Scattering(edge_gain=0.0),
    "specular lobes x0.5": Scattering(lobe_scale=0.5),
    "specular lobes x2": Scattering(lobe_scale=2.0),
    "no window": Scattering(window="none"),
    "Hamming window": Scattering(window="hamming"),
    "range-Doppler, no polar reformatting": Scattering(imaging="range-doppler"),
    "1 px blur": Scattering(blur_px=1.0),
    "5 dominant point returns": Scattering(dominant=5),
    "phase error 1 rad": Scattering(phase_error_rad=1.0),
    "scale errors +-2 %": Scattering(scale_error=0.02),
}


def draw_scattering(preset: str, rng: np.random.Generator, overrides: dict[str, Any] | None = None) -> Scattering:
    """Draw one frame's Scattering from a ``VARIETY_PRESETS`` preset; ``overrides`` fix parameters."""
    if preset not in VARIETY_PRESETS:
        raise RadarError(f"unknown variety preset {preset!r}; one of {', '.join(VARIETY_PRESETS)}", field="variety")
    values: dict[str, Any] = {}
    for name, spec in VARIETY_PRESETS[preset].items():
        if isinstance(spec[0], str) or len(spec) != 2:
            values[name] = spec[int(rng.integers(len(spec)))]
        elif isinstance(spec[0], int) and isinstance(spec[1], int):
            values[name] = int(rng.integers(spec[0], spec[1] + 1))
        else:
            values[name] = float(rng.uniform(spec[0], spec[1]))
    for name, value in (overrides or {}).items():
        if name not in Scattering.__dataclass_fields__:
            raise RadarError(
                f"unknown scattering parameter {name!r} (see inference.simulation.scene.Scattering)", field="variety"
            )
        values[name] = value
    return Scattering(**values)


_DENSE: dict[int, tuple[Vec, Vec]] = {}


def _dense_skin(model: TargetModel) -> tuple[Vec, Vec]:
    """The model's skin and its normals (computed once per model)."""
    from inference.simulation.targets import surface_normals

    key = id(model.surface)
    if key not in _DENSE:
        _DENSE.clear()
        _DENSE[key] = (model.surface, surface_normals(model.surface))
    return _DENSE[key]


def _centres_echo(
    model: TargetModel, imager: Imager, rot: Vec, sc: Scattering, rng: np.random.Generator
) -> NDArray[np.complex128]:
    """The scattering-centre physics' echo: rotate, cull hidden scatterers, their amplitudes, the NUFFT."""
    radar = imager.radar
    if sc.scatterers == "dense":
        skin, skin_normals = _dense_skin(model)
        body = skin + rng.uniform(-0.04, 0.04, skin.shape)
        kinds = np.full(len(skin), FLAT, np.int8)
        pts, normals = body @ rot.T, skin_normals @ rot.T
    else:
        kinds = model.kinds
        pts, normals = model.scatterers @ rot.T, model.normals @ rot.T
    los = projection_matrix(radar)[0]
    seen = visible(pts, normals, kinds, los)
    if sc == DEFAULT_SCATTERING:
        amps = scatterer_amplitudes(normals[seen], kinds[seen], los, rng)
    else:
        amps = scatterer_amplitudes(
            normals[seen], kinds[seen], los, rng, sc.lobe_scale, sc.edge_gain, dense=sc.scatterers == "dense"
        )
    p = pts[seen]
    if sc.dominant:
        pick = rng.choice(len(p), size=min(sc.dominant, len(p)), replace=False)
        amps[pick] = np.abs(amps).max() * np.exp(2j * np.pi * rng.random(len(pick)))
    if sc.scale_error:
        p = p * np.array([1.0 + rng.uniform(-1, 1) * sc.scale_error, 1.0 + rng.uniform(-1, 1) * sc.scale_error, 1.0])
    if sc.imaging == "range-doppler":
        echo = polar_echo(radar, p, amps)
    else:
        echo = imager.echo(p, amps)
    return echo


def po_mesh(model: TargetModel) -> tuple[Mesh, list[str]]:
    """Return the model's facets checked for physical optics (``po.checked_mesh``) and what was done to them."""
    if model.mesh is None:
        raise ModelFileError(
            f"model {model.name!r} has no facets (a point cloud): physics 'po' needs a triangle mesh", field="model"
        )
    key = id(model.mesh)
    if key not in _PO_MESH:
        _PO_MESH.clear()
        _PO_MESH[key] = checked_mesh(model.mesh.vertices, model.mesh.faces, model.name)
    return _PO_MESH[key]


_PO_MESH: dict[int, tuple[Mesh, list[str]]] = {}


def _po_echo(
    model: TargetModel, imager: Imager, rot: Vec, sc: Scattering, rng: np.random.Generator
) -> NDArray[np.complex128]:
    """The physical-optics echo of the model's facets (``inference.simulation.po``)."""
    mesh, _ = po_mesh(model)
    pm = prepared(mesh, sc.facet_m)
    options = POOptions(sc.facet_m, sc.bounces, sc.roughness)
    scale = (1.0, 1.0)
    if sc.scale_error:
        scale = (1.0 + rng.uniform(-1, 1) * sc.scale_error, 1.0 + rng.uniform(-1, 1) * sc.scale_error)
    if sc.imaging == "range-doppler":
        pts, amps = po_sources(pm, rot, imager.radar, options, rng)
        return polar_echo(imager.radar, pts * np.array([scale[0], scale[1], 1.0]), amps)
    return po_echo(pm, rot, imager, options, rng, scale)


def simulate(
    model: TargetModel,
    imager: Imager,
    angles_deg: tuple[float, float, float],
    snr_db: float | None,
    seed: int,
    scattering: Scattering = DEFAULT_SCATTERING,
) -> Frame:
    """Simulate one frame: rotate, cull hidden scatterers, image, add noise at ``snr_db`` (None: noise-free).

    ``scattering`` other than the default changes how (``Scattering``); the default draws the
    same random numbers in the same order as before it existed, so every data set stays the same.
    """
    rng = np.random.default_rng(seed)
    rot = rotation_matrix(*angles_deg)
    sc = scattering
    radar = imager.radar
    if sc.physics == "po":
        echo = _po_echo(model, imager, rot, sc, rng)
    else:
        echo = _centres_echo(model, imager, rot, sc, rng)
    if sc.phase_error_rad:
        t = np.linspace(-1.0, 1.0, radar.n_azimuth)
        curve = rng.uniform(-1, 1) * t**2 + rng.uniform(-1, 1) * t**3
        echo = echo * np.exp(1j * sc.phase_error_rad * curve / max(np.abs(curve).max(), 1e-9))[None, :]
    if snr_db is not None:
        echo = add_noise(echo, snr_db, rng)
    if sc.window == "taylor":
        image = imager.image_from_echo(echo)
    else:
        w = np.outer(window_1d(radar.n_range, sc.window, 0), window_1d(radar.n_azimuth, sc.window, 0))
        image = imager.image_from_echo(echo, w)
    if sc.blur_px:
        from scipy.ndimage import gaussian_filter

        image = gaussian_filter(np.abs(image), sc.blur_px).astype(np.complex128)
    label = label_mask(imager, model.surface @ rot.T)
    return Frame(image, label, angles_deg, snr_db)


# ``gsa simulate --variety robust``: every frame draws its own Scattering from these ranges
# (uniform, or a choice), so a training set spans what the robustness benchmark varies.
VARIETY_PRESETS: dict[str, dict[str, tuple[Any, ...]]] = {
    "robust": {
        "scatterers": ("lattice", "dense"),
        "edge_gain": (0.0, 1.0),
        "lobe_scale": (0.5, 2.0),
        "window": ("taylor", "hamming", "none"),
        "imaging": ("polar", "polar", "range-doppler"),
        "dominant": (0, 5),
        "phase_error_rad": (0.0, 1.0),
        "scale_error": (0.0, 0.02),
        "blur_px": (0.0, 1.0),
    },
}


def mirror_pair_iou(
    model: TargetModel, imager: Imager, n: int = 64, seed: int = 0, max_angle_deg: float = 45.0
) -> dict[str, float]:
    """How alike the labels of an attitude (z, y, x) and its near-mirror (z, -y, -x) are, over ``n`` random attitudes.

    The near-mirror is the reflection through the body xy plane seen through the image
    plane: ``R(z, -y, -x) = N R(z, y, x) N`` with ``N = diag(1, 1, -1)``, so a target exactly
    symmetric about its body xy plane gives identical labels (IoU 1) and a frame cannot tell
    the two apart. Returns the mean, median and smallest IoU.
    """
    rng = np.random.default_rng(seed)
    ious = []
    for z, y, x in rng.uniform(-max_angle_deg, max_angle_deg, (n, 3)):
        a = label_mask(imager, model.surface @ rotation_matrix(z, y, x).T)
        b = label_mask(imager, model.surface @ rotation_matrix(z, -y, -x).T)
        ious.append(float(mask_iou(a, b)))
    return {
        "mean": round(float(np.mean(ious)), 4),
        "median": round(float(np.median(ious)), 4),
        "min": round(float(np.min(ious)), 4),
        "attitudes": n,
    }
