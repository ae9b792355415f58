"""The target's mean cross section by aspect: a flat plate against its closed form, and the shipped table against
the exact facet integrals (``po_echo_direct``) of the target's own mesh."""

import math

import numpy as np
import pytest

from inference.simulation.mesh import plate_mesh
from inference.simulation.po import po_echo_direct, prepared
from inference.simulation.radar import Radar
from inference.simulation.targets import BUILTIN_TARGETS, DEFAULT_TARGET
from scene.cross_section import DATA, direction, for_target, grid
from scene.cross_section_build import FACET_M, mean_rcs_m2, mesh_fingerprint, observation_rotation, target_mesh
from scene.errors import SceneError

C = 299_792_458.0


def _plate_mean_closed_form(a_m: float) -> float:
    """A square plate of side a facing the radar, its PO cross section |K|^2 (n.K^)^2 A^2 / (4 pi) sinc^2(K.u a / 2)
    averaged over the Table 3 band (15 GHz +- 0.8 GHz) and a 5.1 deg sweep across one of its sides."""
    k_c = 4 * math.pi * 15e9 / C
    half_band = 4 * math.pi * 0.8e9 / C
    half_cross = k_c * math.radians(5.1) / 2
    kx = np.linspace(k_c - half_band, k_c + half_band, 801)
    ky = np.linspace(-half_cross, half_cross, 4001)
    x = ky * a_m / 2
    sinc2 = np.where(x == 0, 1.0, (np.sin(x) / np.where(x == 0, 1.0, x)) ** 2)
    return float(np.mean(kx**2) * (a_m * a_m) ** 2 / (4 * math.pi) * np.mean(sinc2))


@pytest.mark.parametrize("side_m", [0.6, 1.0])
def test_a_flat_plate_against_its_closed_form(side_m):
    """Broadside at the carrier a plate has 4 pi A^2 / lambda^2; swept over 5.1 deg its lobe (lambda / a wide) is
    averaged down by about lambda / (2 a dtheta) (0.19 for 0.6 m, 0.11 for 1 m): within 0.3 dB of the closed form."""
    plate = plate_mesh(np.zeros(3), np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0]), side_m, side_m)
    ours = mean_rcs_m2(plate, np.array([1.0, 0.0, 0.0]))
    assert 10 * math.log10(ours / _plate_mean_closed_form(side_m)) == pytest.approx(0.0, abs=0.3)


def test_shipped_table_against_exact_facet_integrals():
    """At two of the table's directions (a panel's flash and a dim aspect), the shipped value against the exact
    PO sum of every lit facet at two frequencies (of 16 across the band) and 256 angles across the aperture: within
    1 dB. The angles must be fine: a panel's flash is 0.05 deg wide, and 16 angles that happen to hit its peak make
    the mean 6 dB too bright."""
    table = for_target(DEFAULT_TARGET)
    mesh = target_mesh(DEFAULT_TARGET)
    pm = prepared(mesh, FACET_M)
    cols = np.tile(np.arange(256), 2)
    rows = np.repeat([4, 12], 256)
    for az, el in [(0.0, -30.0), (200.0, 40.0)]:
        los = direction(az, el)
        exact = po_echo_direct(pm, observation_rotation(los), Radar(n_range=16, n_azimuth=256), samples=(rows, cols))
        ref = float(np.mean(np.abs(exact) ** 2))
        shipped = float(table(los[:, None])[0])
        assert 10 * math.log10(shipped / ref) == pytest.approx(0.0, abs=1.0), (az, el)


def test_table_covers_the_sphere_and_interpolates_between_nodes():
    """Every direction has a value; between two nodes the value lies between theirs (log-linear)."""
    table = for_target(DEFAULT_TARGET)
    rng = np.random.default_rng(1)
    u = rng.normal(size=(3, 500))
    values = table(u / np.linalg.norm(u, axis=0))
    assert np.all(np.isfinite(values)) and np.all(values > 0)
    az, el = grid()
    a, b = table(direction(az[3], el[10])[:, None])[0], table(direction(az[4], el[10])[:, None])[0]
    mid = table(direction(0.5 * (az[3] + az[4]), el[10])[:, None])[0]
    assert min(a, b) <= mid <= max(a, b)
    assert mid == pytest.approx(math.sqrt(a * b), rel=1e-9)


def test_a_target_without_a_table_is_refused():
    with pytest.raises(SceneError) as info:
        for_target("no-such-target")
    assert "no-such-target" in str(info.value) and "python -m scene.cross_section_build" in str(info.value)


@pytest.mark.parametrize("name", sorted(BUILTIN_TARGETS))
def test_each_shipped_table_was_made_from_todays_mesh(name):
    """A mesh changed since its table was made would plan with another target's cross section."""
    with np.load(DATA / f"{name}-rcs.npz", allow_pickle=False) as f:
        assert str(f["mesh_sha256"]) == mesh_fingerprint(target_mesh(name)), "python -m scene.cross_section_build"
