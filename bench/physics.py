"""Physical optics beside the scattering-centre simulator (issue 41): the look, the speed, the fast path's error.

Writes the "Physical optics" section of BENCHMARKS.md and bench/physics.png (docs/networks.md's figure).
Run with `python -m bench.physics` (about 3 minutes on 2 cores).

1. The figure: four attitudes of the default target, noise-free, in both physics (PO with roughness 0 and
   0.3), the label's outline over each.
2. Speed: `simulate` alone, 20 attitudes (seed 85000), one process, the PO mesh prepared once (as a data set
   does); `generate` of an 80-frame PO set on 2 processes (label, normalisation, files and mesh preparation included).
3. The fast path's error: off specular against the closed-form plate echo (a lone wing, a plate to edge-on);
   on the whole target against the exact per-sample PO integral (`po.po_echo_direct` on 400 random k-samples,
   shadows per column), windowed, for 6 attitudes.
"""

from __future__ import annotations

import sys
import tempfile
import time
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from bench.common import machine
from bench.sections import replace_section
from inference.rotations import rotation_matrix
from inference.simulation.dataset import DatasetSpec, generate
from inference.simulation.po import POOptions, po_echo, po_echo_direct, prepared
from inference.simulation.radar import Imager, Radar
from inference.simulation.scene import Scattering, po_mesh, simulate
from inference.simulation.targets import tiangong_like

TITLE = "Physical optics"
PLOT = Path("bench/physics.png")
SEED = 85_000
FIGURE_ATTITUDES = ((0.0, 0.0, 0.0), (30.0, -20.0, 10.0), (-25.0, 35.0, -15.0), (40.0, 10.0, 40.0))


def _log(msg: str) -> None:
    print(f"bench.physics: {msg}", file=sys.stderr, flush=True)


def figure(model, imager: Imager) -> None:  # type: ignore[no-untyped-def]
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from scipy.ndimage import binary_erosion

    rows = (
        ("scattering centres (default)", Scattering()),
        ("physical optics", Scattering(physics="po")),
        ("physical optics, roughness 0.3", Scattering(physics="po", roughness=0.3)),
    )
    radar = imager.radar
    extent = [-radar.extent_m[1] / 2, radar.extent_m[1] / 2, radar.extent_m[0] / 2, -radar.extent_m[0] / 2]
    fig, axes = plt.subplots(len(rows), len(FIGURE_ATTITUDES), figsize=(11, 8.4), squeeze=False)
    for i, (name, sc) in enumerate(rows):
        for j, ang in enumerate(FIGURE_ATTITUDES):
            f = simulate(model, imager, ang, None, SEED + j, sc)
            db = 20 * np.log10(np.abs(f.image) / np.abs(f.image).max() + 1e-12)
            ax = axes[i, j]
            ax.imshow(np.clip(db, -40, 0), cmap="gray", extent=extent, vmin=-40, vmax=0)
            edge = f.label & ~binary_erosion(f.label)
            rr, cc = np.nonzero(edge)
            ax.scatter(
                (cc - radar.n_azimuth / 2) * radar.cross_range_cell_m,
                (rr - radar.n_range / 2) * radar.range_cell_m,
                s=0.15,
                c="#ff7f0e",
                alpha=0.6,
            )
            ax.set_xlim(extent[:2])
            ax.set_ylim(extent[2:])
            ax.tick_params(labelsize=6)
            if i == 0:
                ax.set_title(f"z {ang[0]:.0f}, y {ang[1]:.0f}, x {ang[2]:.0f} deg", fontsize=8)
            if j == 0:
                ax.set_ylabel(f"{name}\nrange (m)", fontsize=8)
            if i == len(rows) - 1:
                ax.set_xlabel("cross-range (m)", fontsize=7)
    fig.suptitle("The same attitudes in both physics, noise-free, 40 dB shown; orange: the label's outline", fontsize=9)
    fig.tight_layout()
    fig.savefig(PLOT, dpi=110)
    plt.close(fig)


def speed(model, imager: Imager) -> dict[str, float]:  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(SEED)
    attitudes = [tuple(a) for a in rng.uniform(-45, 45, (20, 3))]
    out = {}
    for name, sc in (
        ("scattering centres (default)", Scattering()),
        ("physical optics", Scattering(physics="po")),
        ("physical optics, roughness 0.3", Scattering(physics="po", roughness=0.3)),
        ("physical optics, 2 bounces", Scattering(physics="po", bounces=2)),
        ("physical optics, 0.1 m facets", Scattering(physics="po", facet_m=0.1)),
        ("physical optics, range-Doppler", Scattering(physics="po", imaging="range-doppler")),
    ):
        simulate(model, imager, attitudes[0], 5.0, 0, sc)  # prepares the mesh and its ray engine once
        t0 = time.perf_counter()
        for k, ang in enumerate(attitudes):
            simulate(model, imager, ang, 5.0, k, sc)
        out[name] = (time.perf_counter() - t0) / len(attitudes)
        _log(f"{name}: {1000 * out[name]:.0f} ms a frame")
    spec = DatasetSpec(80, seed=SEED, physics="po", shard_size=40)
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        generate(spec, Path(tmp) / "po", imager.radar, workers=2, progress=False)
        out["generate"] = (time.perf_counter() - t0) / spec.n
    return out


def accuracy(model, imager: Imager, facet_m: float, n_samples: int = 400) -> list[float]:  # type: ignore[no-untyped-def]
    radar = imager.radar
    mesh, _ = po_mesh(model)
    pm = prepared(mesh, facet_m)
    w2 = imager.window_2d()
    rng = np.random.default_rng(SEED + 1)
    errors = []
    for ang in rng.uniform(-45, 45, (6, 3)):
        rot = rotation_matrix(*ang)
        fast = po_echo(pm, rot, imager, POOptions(facet_m=facet_m), rng)
        m, n = rng.integers(0, radar.n_range, n_samples), rng.integers(0, radar.n_azimuth, n_samples)
        exact = po_echo_direct(pm, rot, radar, samples=(m, n))
        w = w2[m, n]
        errors.append(float(np.linalg.norm(w * (fast[m, n] - exact)) / np.linalg.norm(w * exact)))
    return errors


def plate_closed_form(radar: Radar, rot: np.ndarray, a: float, b: float) -> np.ndarray:
    """The closed-form PO echo of a centred a x b plate (body normal x, sides along y and z) turned by ``rot``."""
    nr, na = radar.n_range, radar.n_azimuth
    kc = 4 * np.pi * radar.carrier_hz / 299_792_458.0
    kx = kc + 2 * np.pi / (nr * radar.range_cell_m) * np.arange(-nr // 2, nr // 2)
    ky = 2 * np.pi / (na * radar.cross_range_cell_m) * np.arange(-na // 2, na // 2)
    kv = np.stack(np.broadcast_arrays(kx[:, None], ky[None, :], 0.0), -1)
    n, u, v = rot[:, 0], rot[:, 1], rot[:, 2]
    sincs = np.sinc(kv @ u * a / (2 * np.pi)) * np.sinc(kv @ v * b / (2 * np.pi))
    return np.asarray(np.sqrt(4 * np.pi) / (4 * np.pi) * np.abs(kv @ n) * a * b * sincs)


def off_specular(imager: Imager) -> dict[str, list[tuple[float, float, float]]]:
    """The fast path against closed forms off specular: (angle, energy error dB, windowed rms error) per aspect.

    The default target's larger wing (5.5 m x 2.2 m) alone, turned 30-80 deg off its normal about two axes, on the
    paper's radar; a 0.5 m plate at 10 GHz from broadside to edge-on (64 x 64).
    """
    from scipy.spatial.transform import Rotation

    from inference.simulation.mesh import plate_mesh
    from inference.simulation.po import PreparedMesh

    out: dict[str, list[tuple[float, float, float]]] = {}
    small = Imager(Radar(carrier_hz=10e9, n_range=64, n_azimuth=64))
    cases = (
        ("lone wing 5.5 m x 2.2 m, 0.2 m facets, 30-80 deg off", imager, 5.5, 2.2, (30, 39, 50, 60, 70, 74, 80)),
        ("plate 0.5 m, 10 GHz, broadside to edge-on", small, 0.5, 0.5, (0, 10, 30, 60, 80, 85, 88, 89, 89.5, 90)),
    )
    for name, im, a, b, degrees in cases:
        pm = PreparedMesh(plate_mesh(np.zeros(3), [0, 1, 0], [0, 0, 1], a, b), 0.2)
        w = im.window_2d()
        rows = []
        for axis in ([0.0, 0.0, 1.0], [0.0, 0.6, 0.8]):
            for deg in degrees:
                rot = Rotation.from_rotvec(np.radians(deg) * np.asarray(axis)).as_matrix()
                fast = po_echo(pm, rot, im, POOptions(), np.random.default_rng(0))
                exact = plate_closed_form(im.radar, rot, a, b)
                db = 20 * np.log10(np.linalg.norm(w * fast) / np.linalg.norm(w * exact))
                rms = np.linalg.norm(w * (fast - exact)) / np.linalg.norm(w * exact)
                rows.append((float(deg), float(db), float(rms)))
        out[name] = rows
        _log(f"{name}: worst {max(abs(r[1]) for r in rows):.3f} dB, {100 * max(r[2] for r in rows):.2f} % rms")
    return out


def main() -> int:
    model = tiangong_like()
    imager = Imager(Radar())
    t0 = time.perf_counter()
    figure(model, imager)
    _log(f"figure written to {PLOT}")
    times = speed(model, imager)
    err = {fm: accuracy(model, imager, fm) for fm in (0.2, 0.1)}
    off = off_specular(imager)
    for fm, e in err.items():
        _log(f"facets {fm} m: fast-path error median {np.median(e):.3f}, max {max(e):.3f}")
    mesh, _ = po_mesh(model)
    lines = [
        f"## {TITLE}",
        "",
        f"Measured {datetime.now(UTC):%Y-%m-%d} on {machine()} by `python -m bench.physics` "
        f"({time.perf_counter() - t0:.0f} s). The default target as {len(mesh.faces):,} facets "
        f"({len(prepared(mesh, 0.2).areas):,} after subdivision to 0.2 m, {len(prepared(mesh, 0.1).areas):,} to 0.1 m); "
        "256 x 256 frames at 5 dB, 20 attitudes in +-45 deg, one process, the mesh and its ray engine prepared once.",
        "",
        "| physics | ms a frame | frames/s |",
        "|---|---|---|",
        *(f"| {k} | {1000 * v:.0f} | {1 / v:.1f} |" for k, v in times.items() if k != "generate"),
        f"| `generate` on 2 processes, 80 PO frames written (mesh preparation and all) | {1000 * times['generate']:.0f} | "
        f"{1 / times['generate']:.1f} |",
        "",
        "The fast path's error off specular, against closed forms (the plate's PO echo on the frame's k-grid): each",
        "aspect turned about two axes, the windowed image's energy in dB and its rms pixel error:",
        "",
        "| surface | aspects | energy error median / worst (dB) | rms error median / worst |",
        "|---|---|---|---|",
        *(
            f"| {name} | {len(rows)} | {np.median([abs(r[1]) for r in rows]):.3f} / {max(abs(r[1]) for r in rows):.3f} | "
            f"{100 * np.median([r[2] for r in rows]):.2f} / {100 * max(r[2] for r in rows):.2f} % |"
            for name, rows in off.items()
        ),
        "",
        "The whole target: `po_echo` against the exact PO integral of every facet lit along each sample's own",
        "direction (`po_echo_direct`, shadows ray-traced per cross-range column) at 400 random samples of the echo,",
        "windowed, 6 attitudes:",
        "",
        "| facets | median error | largest |",
        "|---|---|---|",
        *(f"| {fm} m | {100 * np.median(e):.1f} % | {100 * max(e):.1f} % |" for fm, e in err.items()),
        "",
        "How the fast path works (issue 71): each lit facet's exact integral is written by the divergence theorem",
        "as sources on its edges (Gordon 1975): an edge's two corners, whose amplitudes are smooth in K and are",
        "interpolated from 3 x 3 nodes of the k-patch, so the corners that neighbouring coplanar facets share cancel",
        "exactly, as they do in the integral; an edge nearly at one range (its corner terms blow up and cancel) as",
        "Gauss-Legendre points along it; facets within a few degrees of specular as 5 cm pieces. Obliquity is taken",
        "at each node, the lit set at each cross-range node. Before this, each facet was one point at its centroid,",
        "and the interpolation errors of 0.2 m facets did not cancel: 17-28 dB too bright off specular, a facet",
        "texture over hulls and wings. What still differs from the per-column reference on the whole target is where",
        "a cast shadow's edge moves during the aperture: the fast path fades a facet across the 3 cross-range nodes,",
        "the reference switches it column by column; both are the staircase of 0.2 m facets along the shadow line.",
        "No GPU was at hand for this measurement.",
        "",
        f"![both physics]({PLOT.as_posix()})",
    ]
    replace_section(TITLE, lines)
    return 0


if __name__ == "__main__":
    sys.exit(main())
