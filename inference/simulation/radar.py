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
costs (tests/inference/simulation/test_radar.py). The fast path ``Imager.echo`` computes the
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

import numpy as np
from numpy.typing import NDArray

from inference.errors import RadarError

Vec = NDArray[np.float64]
C_M_S = 299_792_458.0  # speed of light, SI definition


def refuse_unusable(obj: object, checks: tuple[tuple[str, bool], ...]) -> None:
    """Raise RadarError naming the first field whose check failed (and where its meaning is written)."""
    for name, ok in checks:
        if not ok:
            raise RadarError(
                f"{name} = {getattr(obj, name)!r} is not usable (see {type(obj).__module__}.{type(obj).__name__})",
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
        refuse_unusable(self, checks)

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

    Indices are centred (m = -n_r/2 .. n_r/2 - 1 at rows 0..n_r-1). ``c`` of shape (K, P) gives P
    transforms of the same sources, (P, n_r, n_a). A non-uniform FFT
    of type 1 by fast Gaussian gridding (Greengard & Lee 2004, SIAM Review 46:443) on a
    2x oversampled grid: each source is spread over ``2 * spread`` points per axis,
    one FFT, then deconvolution. ``spread`` 4 is accurate to ~2e-4 of the peak, 6 to
    ~3e-6 (tests/inference/simulation/test_radar.py). Cost: O(K spread^2 + N^2 log N).
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
    m = np.arange(-n_r // 2, n_r // 2)
    n = np.arange(-n_a // 2, n_a // 2)
    deconv = np.outer(np.sqrt(np.pi / tau_r) * np.exp(m**2 * tau_r), np.sqrt(np.pi / tau_a) * np.exp(n**2 * tau_a))
    if c.ndim == 2:  # several coefficient sets on the same sources: gridded in one compiled pass, FFTs pruned
        grid = np.zeros((big_r, big_a, c.shape[1]), np.complex128)
        from inference.simulation.kernels import spread_columns

        spread_columns(l_r[:, 0], l_a[:, 0], g_r, g_a, np.ascontiguousarray(c, np.complex128), grid)
        half = scipy.fft.fft(grid, axis=1)[:, np.mod(n, big_a)]  # only the output's columns go on to the next pass
        spectra = scipy.fft.fft(half, axis=0)[np.mod(m, big_r)] / (big_r * big_a)
        return np.asarray(np.moveaxis(spectra, 2, 0) * deconv)
    index = (np.mod(l_r, big_r)[:, :, None] * big_a + np.mod(l_a, big_a)[:, None, :]).ravel()
    weights = ((c[:, None] * g_r)[:, :, None] * g_a[:, None, :]).ravel()
    grid = np.bincount(index, weights.real, big_r * big_a) + 1j * np.bincount(index, weights.imag, big_r * big_a)
    spectrum = scipy.fft.fft2(grid.reshape(big_r, big_a)) / (big_r * big_a)
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


def window_1d(n: int, kind: str, sidelobe_db: float) -> Vec:
    if kind == "taylor":
        return taylor_window(n, sidelobe_db)
    if kind == "hamming":
        return np.hamming(n)
    return np.ones(n)


def nufft_columns(
    u: Vec, c: NDArray[np.complex128], n_r: int, spread: int = 3, chunk: int = 32
) -> NDArray[np.complex128]:
    """Return S[m, j] = sum_k c[k, j] exp(-2 pi i m (u[k, j] - n_r/2) / n_r) for every column j of u, c [K, J].

    One 1-D type-1 NUFFT per column, all columns gridded at once (the same Gaussian gridding
    as ``nufft_type1`` along its first axis, 2x oversampled, ``2 * spread`` taps per source),
    then one FFT down the columns and the deconvolution; ``chunk`` columns at a time bound the
    memory (K x chunk x 2 spread weights).
    """
    import scipy.fft

    k_src, n_col = u.shape
    over = 2
    big = over * n_r
    tau = math.pi * spread / (n_r * n_r * over * (over - 0.5))
    h = 2.0 * np.pi / big
    taps = np.arange(-spread + 1, spread + 1)
    m = np.arange(-n_r // 2, n_r // 2)
    deconv = np.sqrt(np.pi / tau) * np.exp(m**2 * tau) / big
    out = np.empty((n_r, n_col), np.complex128)
    for j0 in range(0, n_col, chunk):
        j1 = min(j0 + chunk, n_col)
        x = np.mod(2.0 * np.pi * (u[:, j0:j1] - n_r / 2) / n_r, 2.0 * np.pi)  # (K, J')
        base = np.floor(x / h).astype(np.int64)
        # Fast Gaussian gridding: exp(-(t h - d)^2 / 4 tau) = exp(-d^2 / 4 tau) exp(d h / 2 tau)^t exp(-(t h)^2 / 4 tau),
        # d = x - base h: two exponentials a source instead of one a tap.
        d = x - base * h
        e1 = c[:, j0:j1] * np.exp(-(d**2) / (4.0 * tau))
        e2 = np.exp(d * h / (2.0 * tau))
        g = np.empty((*d.shape, len(taps)))  # real tap weights; times e1 below, real and imaginary parts apart
        g[..., spread - 1] = 1.0
        for t in range(spread, len(taps)):
            g[..., t] = g[..., t - 1] * e2
        inv = 1.0 / e2
        for t in range(spread - 2, -1, -1):
            g[..., t] = g[..., t + 1] * inv
        g *= np.exp(-((taps * h) ** 2) / (4.0 * tau))
        cols = j1 - j0
        index = (np.mod(base[..., None] + taps, big) * cols + np.arange(cols)[None, :, None]).ravel()
        grid = np.bincount(index, (g * e1.real[..., None]).ravel(), big * cols) + 1j * np.bincount(
            index, (g * e1.imag[..., None]).ravel(), big * cols
        )
        spectrum = scipy.fft.fft(grid.reshape(big, cols), axis=0)
        out[:, j0:j1] = spectrum[np.mod(m, big)] * deconv[:, None]
    return out


def polar_echo(radar: Radar, points_obs: Vec, amplitudes: NDArray[np.complex128]) -> NDArray[np.complex128]:
    """Return the echo on the radar's real polar samples (as ``polar_echo_direct``), by a 1-D NUFFT per aspect.

    Along each aspect the frequencies are uniform, so each column is a type-1 NUFFT of the
    scatterers' ranges (``nufft_columns``, all aspects gridded together; design/measurements.md,
    "The NUFFT echo").
    """
    nr, na = radar.n_range, radar.n_azimuth
    b = math.radians(radar.aperture_deg) / na * np.arange(-na // 2, na // 2, dtype=np.float64)
    los, _ = line_of_sight(math.radians(radar.pitch_deg), b)  # (3, na)
    ranges = points_obs @ los  # (K, na)
    kc = 4.0 * math.pi * radar.carrier_hz / C_M_S
    c = amplitudes[:, None] * np.exp(-1j * kc * ranges)
    return nufft_columns(ranges / radar.range_cell_m + nr / 2, c, nr)
