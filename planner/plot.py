"""Draw a plan: ground track with the station's passes, elevation over the chosen pass, node-line error."""

from __future__ import annotations

import numpy as np

from planner.access import look_angles, mask_deg
from planner.alignment import node_miss_km


def plot_plan(plan, path: str, title: str = "") -> None:  # type: ignore[no-untyped-def]
    """Write a three-panel PNG of ``plan`` (a planner.plan.Plan) to ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(17, 5), gridspec_kw={"width_ratios": [1.6, 1, 1]})
    tgt, frames, station = plan.target_trajectory, plan.frames, plan.station
    chosen = plan.chosen
    t_c = (
        chosen.t_access_s if chosen is not None else float(plan.windows.culmination_s[0]) if len(plan.windows) else 0.0
    )

    # Ground track over two revolutions centred on T_access.
    t = np.linspace(max(0.0, t_c - 6000.0), min(plan.duration_s, t_c + 6000.0), 2000)
    r, _ = tgt.state(t)
    r_itrs = frames.to_itrs(t, r)
    lat = np.degrees(np.arctan2(r_itrs[2], np.hypot(r_itrs[0], r_itrs[1])))
    lon = np.degrees(np.arctan2(r_itrs[1], r_itrs[0]))
    look = look_angles(r, t, station, frames)
    visible = look.elevation_deg >= mask_deg(station, look.azimuth_deg)
    ax = axes[0]
    lon_plot = np.where(np.abs(np.diff(lon, prepend=lon[0])) > 180, np.nan, lon)
    ax.plot(lon_plot, lat, color="0.6", lw=1, label="target ground track")
    ax.plot(np.where(visible, lon_plot, np.nan), lat, color="tab:blue", lw=2.5, label="visible from the station")
    ax.plot(station.longitude_deg, station.latitude_deg, "r^", ms=10, label="station")
    if chosen is not None:
        rc, _ = tgt.state(t_c)
        rci = frames.to_itrs(np.array([t_c]), rc)
        ax.plot(
            np.degrees(np.arctan2(rci[1], rci[0])),
            np.degrees(np.arctan2(rci[2], np.hypot(rci[0], rci[1]))),
            "k*",
            ms=14,
            label="T_access",
        )
    ax.set(
        xlim=(-180, 180),
        ylim=(-90, 90),
        xlabel="longitude (deg)",
        ylabel="latitude (deg)",
        title="ground track around the chosen access",
    )
    ax.grid(alpha=0.3)
    ax.legend(loc="lower left", fontsize=8)

    # Elevation over the chosen pass.
    ax = axes[1]
    if chosen is not None:
        k = chosen.pass_index
        tp = np.linspace(plan.windows.rise_s[k], plan.windows.set_s[k], 400)
        rp, _ = tgt.state(tp)
        el = look_angles(rp, tp, station, frames).elevation_deg
        ax.plot((tp - t_c) / 60.0, el, color="tab:blue")
        ax.axvline(0.0, color="k", ls="--", label="T_access")
        ax.set(xlabel="minutes from T_access", ylabel="elevation (deg)", title="the chosen pass")
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)

    # Node-line miss around T_access, with the changed observer's own propagation.
    ax = axes[2]
    if chosen is not None and plan.observer_trajectory is not None:
        tm = np.linspace(t_c - 60.0, t_c + 60.0, 241)
        rt, vt = tgt.state(tm)
        ro, vo = plan.observer_trajectory.state(tm)
        n = np.cross(ro, vo, axis=0)
        miss, _ = node_miss_km(rt, vt, n / np.linalg.norm(n, axis=0))
        ax.plot(tm - t_c, miss, color="tab:red")
        ax.axvline(0.0, color="k", ls="--")
        ax.set(
            xlabel="seconds from T_access",
            ylabel="node line to target (km)",
            title=f"alignment, dHa {chosen.delta_ha_km:.1f} km, dHp {chosen.delta_hp_km:.1f} km",
        )
        ax.grid(alpha=0.3)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
