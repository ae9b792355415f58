"""ISAR imaging of a scattering-centre target (DESIGN.md section 3; Hou et al. 2023, section 4.2).

Geometry. The observation frame has X along the line of sight at the aperture's
centre (target to radar) and Y along its rate of change, so the image plane is XY
and Z is lost. The line of sight at pitch a and azimuth b is
``r = (cos a cos b, cos a sin b, sin a)``; a scatterer at ``p`` (observation frame)
has range ``r . p`` and Doppler ``2 (dr/dt . p) / lambda``. The target's attitude is
the rotation ``R = Rz(z) Ry(y) Rx(x)`` from body to observation frame.

Echo and image. The echo of scatterers ``a_k`` at ``p_k`` over frequency f and
aspect b is ``s(f, b) = sum_k a_k exp(-j 4 pi f / c r(b) . p_k)``: samples of the
target's spectrum on a polar grid in k-space. Polar-format imaging resamples them on
the Cartesian grid inscribed in that annulus, windows them and inverse-FFTs.
``cartesian_echo_direct`` + ``image_from_echo`` is that chain with the Cartesian
samples summed exactly (the reference, O(K N^2)); ``polar_echo_direct`` +
``polar_format`` is the textbook chain with interpolation, and ``range_doppler``
the 2-D FFT without reformatting, both kept to measure what each approximation
costs (tests/inference/test_isar.py). The fast path ``Imager.echo`` computes the
same Cartesian samples as the reference by a non-uniform FFT (``nufft_type1``),
to ~2e-4 of the peak, far faster than the direct sum (design/measurements.md, "The NUFFT echo").

Noise and SNR. SNR is defined in the echo domain, as the standard ISAR textbooks
do: mean |s|^2 of the noise-free Cartesian echo over the variance of complex white
Gaussian noise added to it. The 2-D FFT then adds up to 10 log10(N_r N_a) = 48 dB of
processing gain, which is why 0 dB frames still image.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from inference.errors import ModelFileError, RadarError
from inference.frames import euler_from_matrix, normalise_frame, rotation_matrix  # noqa: F401 (part of the simulator's API)
from inference.simulation.targets import CURVED, EDGE, FLAT, ISOTROPIC, TargetModel

Vec = NDArray[np.float64]
C_M_S = 299_792_458.0  # speed of light, SI definition


def _refuse_unusable(obj: object, checks: tuple[tuple[str, bool], ...]) -> None:
    """Raise RadarError naming the first field whose check failed (and where its meaning is written)."""
    for name, ok in checks:
        if not ok:
            raise RadarError(
                f"{name} = {getattr(obj, name)!r} is not usable (see inference.simulation.isar.{type(obj).__name__})",
                field=name,
            )


@dataclass(frozen=True, slots=True)
class Radar:
    """Radar and imaging parameters; the defaults are the paper's Table 3.

    ``window_sidelobe_db`` is the Taylor window (nbar 4) applied in both dimensions:
    25 dB keeps the -3 dB widths within 5 % of c/2B and lambda/(2 dtheta).
    """

    carrier_hz: float = 15e9
    bandwidth_hz: float = 1.6e9
    n_range: int = 256
    n_azimuth: int = 256
    aperture_deg: float = 5.1
    pitch_deg: float = 0.0
    window_sidelobe_db: float = 25.0

    def __post_init__(self) -> None:
        checks = (
            ("carrier_hz", self.carrier_hz > 0 and math.isfinite(self.carrier_hz)),
            ("bandwidth_hz", 0 < self.bandwidth_hz < 2 * self.carrier_hz),
            ("n_range", isinstance(self.n_range, int) and 8 <= self.n_range <= 4096 and self.n_range % 2 == 0),
            ("n_azimuth", isinstance(self.n_azimuth, int) and 8 <= self.n_azimuth <= 4096 and self.n_azimuth % 2 == 0),
            ("aperture_deg", 0 < self.aperture_deg <= 30),
            ("pitch_deg", -90 < self.pitch_deg < 90),
            ("window_sidelobe_db", 13 <= self.window_sidelobe_db <= 100),
        )
        _refuse_unusable(self, checks)

    @property
    def wavelength_m(self) -> float:
        return C_M_S / self.carrier_hz

    @property
    def range_cell_m(self) -> float:
        """Return c / 2B, the range pixel (and resolution) in metres."""
        return C_M_S / (2.0 * self.bandwidth_hz)

    @property
    def cross_range_cell_m(self) -> float:
        """Return lambda / (2 dtheta), the cross-range pixel (and resolution) in metres."""
        return self.wavelength_m / (2.0 * math.radians(self.aperture_deg))

    @property
    def extent_m(self) -> tuple[float, float]:
        """Return the frame's size (range, cross-range) in metres."""
        return self.n_range * self.range_cell_m, self.n_azimuth * self.cross_range_cell_m


def line_of_sight(pitch_rad: float, azimuth_rad: Vec | float) -> tuple[Vec, Vec]:
    """Return the line of sight r(b) and its unit rate of change d(b), each (3,) or (3, N)."""
    b = np.asarray(azimuth_rad, float)
    ca, sa = math.cos(pitch_rad), math.sin(pitch_rad)
    r = np.array([ca * np.cos(b), ca * np.sin(b), sa * np.ones_like(b)])
    d = np.array([-np.sin(b), np.cos(b), np.zeros_like(b)])
    return r, d


def projection_matrix(radar: Radar) -> Vec:
    """Return A = (r; d) at the aperture centre: observation-frame points to (range, cross-range) metres."""
    r, d = line_of_sight(math.radians(radar.pitch_deg), 0.0)
    return np.vstack([r, d])


def taylor_window(n: int, sidelobe_db: float) -> Vec:
    """Return a Taylor window (nbar 4), peak 1."""
    from scipy.signal import windows

    return np.asarray(windows.taylor(n, nbar=4, sll=sidelobe_db, norm=True))


def nufft_type1(
    u: Vec, v: Vec, c: NDArray[np.complex128], n_r: int, n_a: int, spread: int = 3
) -> NDArray[np.complex128]:
    """Return S[m, n] = sum_k c_k exp(-2 pi j (m (u_k - n_r/2) / n_r + n (v_k - n_a/2) / n_a)).

    Indices are centred (m = -n_r/2 .. n_r/2 - 1 at rows 0..n_r-1). A non-uniform FFT
    of type 1 by fast Gaussian gridding (Greengard & Lee 2004, SIAM Review 46:443) on a
    2x oversampled grid: each source is spread over ``2 * spread`` points per axis,
    one FFT, then deconvolution. ``spread`` 4 is accurate to ~2e-4 of the peak, 6 to
    ~3e-6 (tests/inference/test_isar.py). Cost: O(K spread^2 + N^2 log N).
    """
    import scipy.fft

    over = 2
    big_r, big_a = over * n_r, over * n_a
    tau_r = math.pi * spread / (n_r * n_r * over * (over - 0.5))
    tau_a = math.pi * spread / (n_a * n_a * over * (over - 0.5))
    x_r = np.mod(2.0 * np.pi * (u - n_r / 2) / n_r, 2.0 * np.pi)
    x_a = np.mod(2.0 * np.pi * (v - n_a / 2) / n_a, 2.0 * np.pi)
    h_r, h_a = 2.0 * np.pi / big_r, 2.0 * np.pi / big_a
    taps = np.arange(-spread + 1, spread + 1)
    l_r = np.floor(x_r / h_r).astype(np.int64)[:, None] + taps
    l_a = np.floor(x_a / h_a).astype(np.int64)[:, None] + taps
    g_r = np.exp(-((l_r * h_r - x_r[:, None]) ** 2) / (4.0 * tau_r))
    g_a = np.exp(-((l_a * h_a - x_a[:, None]) ** 2) / (4.0 * tau_a))
    weights = ((c[:, None] * g_r)[:, :, None] * g_a[:, None, :]).ravel()
    index = (np.mod(l_r, big_r)[:, :, None] * big_a + np.mod(l_a, big_a)[:, None, :]).ravel()
    grid = np.bincount(index, weights.real, big_r * big_a) + 1j * np.bincount(index, weights.imag, big_r * big_a)
    spectrum = scipy.fft.fft2(grid.reshape(big_r, big_a)) / (big_r * big_a)
    m = np.arange(-n_r // 2, n_r // 2)
    n = np.arange(-n_a // 2, n_a // 2)
    deconv = np.outer(np.sqrt(np.pi / tau_r) * np.exp(m**2 * tau_r), np.sqrt(np.pi / tau_a) * np.exp(n**2 * tau_a))
    return spectrum[np.mod(m, big_r)][:, np.mod(n, big_a)] * deconv


@dataclass(frozen=True)
class Imager:
    """Polar-format imaging for one radar: the windows, and the echo of point scatterers."""

    radar: Radar
    window_r: Vec = field(init=False)
    window_a: Vec = field(init=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "window_r", taylor_window(self.radar.n_range, self.radar.window_sidelobe_db))
        object.__setattr__(self, "window_a", taylor_window(self.radar.n_azimuth, self.radar.window_sidelobe_db))

    def pixel_coordinates(self, points_obs: Vec) -> tuple[Vec, Vec]:
        """Return fractional pixel positions (range row, cross-range column) of observation-frame points (N, 3)."""
        a = projection_matrix(self.radar)
        rc = points_obs @ a.T
        u = rc[:, 0] / self.radar.range_cell_m + self.radar.n_range / 2
        v = rc[:, 1] / self.radar.cross_range_cell_m + self.radar.n_azimuth / 2
        return u, v

    def echo(self, points_obs: Vec, amplitudes: NDArray[np.complex128]) -> NDArray[np.complex128]:
        """Return the echo of point scatterers on the Cartesian k-grid (n_range, n_azimuth, centred indices).

        The same numbers as ``cartesian_echo_direct`` (to ~2e-4 of the peak), by a
        non-uniform FFT instead of a direct sum.
        """
        kc = 4.0 * math.pi * self.radar.carrier_hz / C_M_S
        r_los = projection_matrix(self.radar)[0]
        u, v = self.pixel_coordinates(points_obs)
        carrier = amplitudes * np.exp(-1j * kc * (points_obs @ r_los))
        return nufft_type1(u, v, carrier, self.radar.n_range, self.radar.n_azimuth)

    def window_2d(self) -> Vec:
        return np.outer(self.window_r, self.window_a)

    def image_from_echo(self, echo: NDArray[np.complex128], window: Vec | None = None) -> NDArray[np.complex128]:
        """Window a Cartesian echo (centred indices m = -N/2..N/2-1) and form the complex image.

        ``window`` (2-D) replaces the radar's Taylor window.
        """
        import scipy.fft

        w = self.window_2d() if window is None else window
        return np.fft.fftshift(scipy.fft.ifft2(np.fft.ifftshift(w * echo)))

    def render(self, points_obs: Vec, amplitudes: NDArray[np.complex128]) -> NDArray[np.complex128]:
        """Return the noise-free complex image of point scatterers."""
        return self.image_from_echo(self.echo(points_obs, amplitudes))


def add_noise(echo: NDArray[np.complex128], snr_db: float, rng: np.random.Generator) -> NDArray[np.complex128]:
    """Return ``echo`` plus complex white Gaussian noise at ``snr_db`` (mean |echo|^2 over the noise variance)."""
    signal_power = float(np.mean(np.abs(echo) ** 2))
    variance = signal_power / 10.0 ** (snr_db / 10.0)
    noise = rng.standard_normal(echo.shape) + 1j * rng.standard_normal(echo.shape)
    return echo + noise * math.sqrt(variance / 2.0)


def cartesian_echo_direct(
    imager: Imager, points_obs: Vec, amplitudes: NDArray[np.complex128]
) -> NDArray[np.complex128]:
    """Return the echo on the Cartesian k-grid by direct summation (reference; O(K N_r N_a))."""
    radar = imager.radar
    nr, na = radar.n_range, radar.n_azimuth
    kc = 4.0 * math.pi * radar.carrier_hz / C_M_S
    dkx = 2.0 * math.pi / (nr * radar.range_cell_m)
    dky = 2.0 * math.pi / (na * radar.cross_range_cell_m)
    a = projection_matrix(radar)
    xy = points_obs @ a.T
    kx = kc + dkx * np.arange(-nr // 2, nr // 2)
    ky = dky * np.arange(-na // 2, na // 2)
    ex = np.exp(-1j * np.outer(kx, xy[:, 0]))  # (nr, K)
    ey = np.exp(-1j * np.outer(xy[:, 1], ky))  # (K, na)
    return (ex * amplitudes) @ ey


def polar_echo_direct(
    radar: Radar, points_obs: Vec, amplitudes: NDArray[np.complex128]
) -> tuple[NDArray[np.complex128], Vec, Vec]:
    """Return the echo s(f, b) on the radar's real polar samples by direct summation, with f (Hz) and b (rad).

    This is the straightforward simulation (the benchmark's baseline): every
    scatterer, every frequency, every aspect.
    """
    nr, na = radar.n_range, radar.n_azimuth
    f: Vec = radar.carrier_hz + radar.bandwidth_hz / nr * np.arange(-nr // 2, nr // 2, dtype=np.float64)
    b: Vec = math.radians(radar.aperture_deg) / na * np.arange(-na // 2, na // 2, dtype=np.float64)
    los, _ = line_of_sight(math.radians(radar.pitch_deg), b)  # (3, na)
    ranges = points_obs @ los  # (K, na)
    k = 4.0 * math.pi * f / C_M_S  # (nr,)
    echo = np.zeros((nr, na), np.complex128)
    for j in range(na):
        echo[:, j] = np.exp(-1j * np.outer(k, ranges[:, j])) @ amplitudes
    return echo, f, b


def polar_format(imager: Imager, echo: NDArray[np.complex128], f_hz: Vec, b_rad: Vec) -> NDArray[np.complex128]:
    """Resample a polar echo onto the inscribed Cartesian k-grid (bicubic in (k, b)) and form the image."""
    from scipy.ndimage import map_coordinates

    radar = imager.radar
    nr, na = radar.n_range, radar.n_azimuth
    kc = 4.0 * math.pi * radar.carrier_hz / C_M_S
    dkx = 2.0 * math.pi / (nr * radar.range_cell_m)
    dky = 2.0 * math.pi / (na * radar.cross_range_cell_m)
    kx, ky = np.meshgrid(kc + dkx * np.arange(-nr // 2, nr // 2), dky * np.arange(-na // 2, na // 2), indexing="ij")
    k = np.hypot(kx, ky)
    beta = np.arctan2(ky, kx)
    k_axis = 4.0 * math.pi * f_hz / C_M_S
    fi = (k - k_axis[0]) / (k_axis[1] - k_axis[0])
    bi = (beta - b_rad[0]) / (b_rad[1] - b_rad[0])
    re = map_coordinates(echo.real, [fi, bi], order=3, mode="nearest")
    im = map_coordinates(echo.imag, [fi, bi], order=3, mode="nearest")
    return imager.image_from_echo(re + 1j * im)


def range_doppler(imager: Imager, echo: NDArray[np.complex128]) -> NDArray[np.complex128]:
    """Form the image by a plain windowed 2-D FFT of the polar echo (no reformatting: migration smears)."""
    return imager.image_from_echo(echo)


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

    def __post_init__(self) -> None:
        checks = (
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
        _refuse_unusable(self, checks)


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
                f"unknown scattering parameter {name!r} (see inference.simulation.isar.Scattering)", field="variety"
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


def window_1d(n: int, kind: str, sidelobe_db: float) -> Vec:
    if kind == "taylor":
        return taylor_window(n, sidelobe_db)
    if kind == "hamming":
        return np.hamming(n)
    return np.ones(n)


def polar_echo(radar: Radar, points_obs: Vec, amplitudes: NDArray[np.complex128]) -> NDArray[np.complex128]:
    """Return the echo on the radar's real polar samples (as ``polar_echo_direct``), by a 1-D NUFFT per aspect.

    Along each aspect the frequencies are uniform, so each column is a type-1 NUFFT of the
    scatterers' ranges (design/measurements.md, "The NUFFT echo").
    """
    nr, na = radar.n_range, radar.n_azimuth
    b = math.radians(radar.aperture_deg) / na * np.arange(-na // 2, na // 2, dtype=np.float64)
    los, _ = line_of_sight(math.radians(radar.pitch_deg), b)  # (3, na)
    ranges = points_obs @ los  # (K, na)
    kc = 4.0 * math.pi * radar.carrier_hz / C_M_S
    cell = radar.range_cell_m
    echo = np.empty((nr, na), np.complex128)
    for j in range(na):
        c = amplitudes * np.exp(-1j * kc * ranges[:, j])
        u = ranges[:, j] / cell + nr / 2
        echo[:, j] = nufft_type1(u, np.full(len(u), 4.0), c, nr, 8)[:, 0]
    return echo


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
