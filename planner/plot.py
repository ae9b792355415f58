"""Draw a plan: the map (coastlines, night side, both ground tracks, the station and where it sees the
target), the chosen pass on the station's sky, its elevation in UTC, and the node-line error."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from planner.access import look_angles, mask_deg
from planner.alignment import node_miss_km
from planner.coastlines import coastline_lines
from planner.frames import geodetic, ground_track, visibility_circle
from planner.illumination import sun_position_km, sunlit
from planner.propagation import utc

Vec = NDArray[np.float64]


def _broken(lon: Vec, lat: Vec) -> tuple[Vec, Vec]:
    """A track with NaN where it jumps across the antimeridian, so no line crosses the map."""
    jump = np.abs(np.diff(lon, prepend=lon[0])) > 180.0
    return np.where(jump, np.nan, lon), np.where(jump, np.nan, lat)


def feasibility_words(plan) -> str:  # type: ignore[no-untyped-def]
    """The plan's verdict in words, as the figure states it."""
    f = plan.chosen_feasibility
    if plan.chosen is None or f is None:
        return "no candidate was planned" + (f": {plan.notes[0]}" if plan.notes else "")
    return "feasible" if f.feasible else "not feasible: " + "; ".join(f.reasons)


def plot_plan(plan, path: str, title: str = "") -> None:  # type: ignore[no-untyped-def]
    """Write a PNG of ``plan`` (a planner.plan.Plan) to ``path``: the map, the pass, the alignment and, where a burn
    was planned, the fly-by in the target's orbital frame."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.dates as mdates
    import matplotlib.pyplot as plt

    meet = plan.encounter
    fly_by = meet.relative if meet is not None else None
    rows = 3 if fly_by is not None else 2
    fig = plt.figure(figsize=(16, 10 if rows == 2 else 14))
    grid = fig.add_gridspec(rows, 3, height_ratios=[1.25, 1, 1][:rows])
    tgt, frames, station = plan.target_trajectory, plan.frames, plan.station
    chosen = plan.chosen
    t_c = (
        chosen.t_access_s if chosen is not None else float(plan.windows.culmination_s[0]) if len(plan.windows) else 0.0
    )
    when = utc(plan.epoch, t_c)

    # The map: coastlines, the night side at T_access, a revolution of each ground track either side.
    ax = fig.add_subplot(grid[0, :])
    lon_g, lat_g = np.meshgrid(np.linspace(-180, 180, 361), np.linspace(-90, 90, 181))
    r_sun = sun_position_km(plan.epoch, np.array([t_c]))
    s_lat, s_lon, _ = geodetic(frames.to_itrs(np.array([t_c]), r_sun))
    p1, p2 = np.radians(lat_g), np.radians(s_lat[0])
    night = np.sin(p1) * np.sin(p2) + np.cos(p1) * np.cos(p2) * np.cos(np.radians(lon_g - s_lon[0])) < 0.0
    ax.imshow(
        night, extent=(-180, 180, -90, 90), origin="lower", cmap="Greys", vmin=0, vmax=4, alpha=0.9, aspect="auto"
    )
    for line in coastline_lines():
        ax.plot(line[:, 0], line[:, 1], color="0.35", lw=0.6)
    t = np.linspace(max(0.0, t_c - 6000.0), min(plan.duration_s, t_c + 6000.0), 2400)
    lat, lon, h = ground_track(tgt, frames, t)
    r, _ = tgt.state(t)
    look = look_angles(r, t, station, frames)
    seen = look.elevation_deg >= mask_deg(station, look.azimuth_deg)
    lit = sunlit(r, sun_position_km(plan.epoch, t))
    x, y = _broken(lon, lat)
    ax.plot(np.where(lit, x, np.nan), y, color="0.45", lw=1.2, label="target ground track (sunlit)")
    ax.plot(np.where(~lit, x, np.nan), y, color="0.45", lw=1.2, ls=":", label="target in Earth's shadow")
    ax.plot(np.where(seen, x, np.nan), y, color="tab:blue", lw=3, label="target in view of the station")
    if plan.observer_trajectory is not None:
        o_lat, o_lon, _ = ground_track(plan.observer_trajectory, frames, t)
        ax.plot(*_broken(o_lon, o_lat), color="tab:purple", lw=1, ls="--", label="observer ground track")
    c_lat, c_lon = visibility_circle(station, float(np.interp(t_c, t, h)))
    ax.plot(*_broken(c_lon, c_lat), color="tab:red", lw=1.2, ls="--", label="where the station sees the target")
    ax.plot(station.longitude_deg, station.latitude_deg, "r^", ms=10, label="station")
    if chosen is not None:
        a_lat, a_lon, _ = ground_track(tgt, frames, np.array([t_c]))
        ax.plot(a_lon, a_lat, "k*", ms=15, label="target at T_access")
    ax.set(
        xlim=(-180, 180),
        ylim=(-90, 90),
        xlabel="longitude (deg)",
        ylabel="latitude (deg, WGS-84)",
        title=f"ground tracks {utc(plan.epoch, float(t[0])):%Y-%m-%d %H:%M}-{utc(plan.epoch, float(t[-1])):%H:%M} UTC; "
        f"night side shaded at T_access {when:%Y-%m-%d %H:%M:%S} UTC",
    )
    ax.set_xticks(range(-180, 181, 30))
    ax.set_yticks(range(-90, 91, 30))
    ax.grid(alpha=0.25)
    ax.legend(loc="lower left", fontsize=8, ncol=2, framealpha=0.9)

    if chosen is not None:
        k = chosen.pass_index
        tp = np.linspace(plan.windows.rise_s[k], plan.windows.set_s[k], 400)
        rp, _ = tgt.state(tp)
        lp = look_angles(rp, tp, station, frames)
        # The pass on the station's sky: azimuth from north through east, zenith at the centre.
        sky: Any = fig.add_subplot(grid[1, 0], projection="polar")
        ax = sky
        ax.set_theta_zero_location("N")
        ax.set_theta_direction(-1)
        az = np.linspace(0.0, 360.0, 361)
        ax.fill_between(np.radians(az), 90.0 - mask_deg(station, az), 90.0, color="tab:red", alpha=0.15, label="mask")
        ax.plot(np.radians(lp.azimuth_deg), 90.0 - lp.elevation_deg, color="tab:blue", lw=2)
        ra, _ = tgt.state(np.array([t_c]))
        la = look_angles(ra, np.array([t_c]), station, frames)
        ax.plot(np.radians(la.azimuth_deg), 90.0 - la.elevation_deg, "k*", ms=12)
        ax.set_rlim(0, 90)
        ax.set_yticks([0, 30, 60, 90])
        ax.set_yticklabels(["90", "60", "30", "0"])
        ax.set_title("the chosen pass on the station's sky (elevation, deg)", fontsize=10)
        ax.legend(loc="lower left", fontsize=8)

        ax = fig.add_subplot(grid[1, 1])
        times = mdates.date2num([utc(plan.epoch, float(s)) for s in tp])  # type: ignore[no-untyped-call]
        ax.plot(times, lp.elevation_deg, color="tab:blue", label="elevation")
        ax.plot(times, mask_deg(station, lp.azimuth_deg), color="tab:red", ls="--", label="mask at its azimuth")
        ax.axhline(station.radar.min_elevation_deg, color="tab:orange", ls=":", label="radar's imaging limit")
        ax.axvline(float(mdates.date2num(when)), color="k", ls="--", label="T_access")  # type: ignore[no-untyped-call]
        ax.xaxis.set_major_formatter(mdates.DateFormatter("%H:%M:%S"))  # type: ignore[no-untyped-call]
        f = plan.chosen_feasibility
        radar = (
            "" if f is None else f"\nradar at T_access: {f.radar_elevation_deg:.1f} deg, {f.isar_integration_s:.0f} s"
        )
        if f is not None and np.isfinite(f.radar_snr_db):
            radar += f" to image, SNR {f.radar_snr_db:.0f} dB"
        ax.set(xlabel=f"UTC, {when:%Y-%m-%d}", ylabel="elevation (deg)", title="the chosen pass" + radar)
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)

    ax = fig.add_subplot(grid[1, 2])
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
    if fly_by is not None:
        _fly_by_panels(fig, grid, fly_by, meet)
    fig.suptitle(f"{title}\n{feasibility_words(plan)}" if title else feasibility_words(plan), fontsize=12)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _fly_by_panels(fig, grid, fly_by, meet) -> None:  # type: ignore[no-untyped-def]
    """The observer a minute either side of T_access in the target's RTN frame (planner.manoeuvre.relative_motion):
    along-track against radial and against cross-track, and the distance against time."""
    t, (r, a, n) = fly_by.t_s, fly_by.rtn_km
    k0 = int(np.argmin(np.abs(t)))
    ticks = np.isclose(np.mod(t, 10.0), 0.0) & (np.abs(t) > 0)
    for col, (y, name) in enumerate(((r, "radial, up (km)"), (n, "cross-track, orbit normal (km)"))):
        ax = fig.add_subplot(grid[2, col])
        ax.plot(a, y, color="tab:purple", lw=2, label="the observer")
        ax.plot(a[ticks], y[ticks], "o", color="tab:purple", ms=3)
        for k in np.flatnonzero(ticks & np.isclose(np.mod(t, 30.0), 0.0)):
            ax.annotate(
                f"{t[k]:+.0f} s", (a[k], y[k]), textcoords="offset points", xytext=(0, 6), ha="center", fontsize=8
            )
        ax.plot([a[k0], 0.0], [y[k0], 0.0], color="tab:orange", ls="--", label="line of sight at T_access")
        ax.plot(0.0, 0.0, "ko", ms=7, label="the target")
        ax.plot(a[k0], y[k0], "o", mfc="white", mec="tab:purple", ms=8, label="the observer at T_access")
        ax.set(xlabel="along-track (km; the target moves to the right)", ylabel=name)
        ax.set_title("the fly-by in the target's orbital frame (axes to different scales)", fontsize=10)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    ax = fig.add_subplot(grid[2, 2])
    ax.plot(t, np.sqrt(r**2 + a**2 + n**2), color="tab:purple")
    ax.axvline(0.0, color="k", ls="--", label="T_access")
    ax.axhline(meet.closest_approach_km, color="tab:green", ls=":", label=f"closest {meet.closest_approach_km:.1f} km")
    ax.set(
        xlabel="seconds from T_access",
        ylabel="observer to target (km)",
        title=f"{meet.relative_speed_km_s:.2f} km/s; the tracker follows {meet.target_angular_rate_deg_s:.2f} deg/s",
    )
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)


def plot_campaign(campaign, path: str, title: str = "", dispersions=None) -> None:  # type: ignore[no-untyped-def]
    """Write a three-panel PNG of ``campaign`` (a planner.campaign.Campaign) to ``path``: the Delta-v spent over
    the span against the budget, each stretch shaded by what came of it (with ``dispersions``, a list of
    planner.dispersion.SceneDispersion, the trims' 95th-percentile margin on top, and each scene's feasible share);
    each scene's line of sight in the target's orbital frame (the imaging geometry the labelled frames will
    cover); and each scene's fly-by as flown."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.dates as mdates
    import matplotlib.pyplot as plt

    ep = campaign.epoch
    fig, (ax, sky, fly) = plt.subplots(1, 3, figsize=(18, 4.8), gridspec_kw={"width_ratios": [1.7, 1.0, 1.2]})
    for s in campaign.stretches:
        colour = "#2ca02c" if s.scene is not None else "#d62728"
        ax.axvspan(utc(ep, s.t0_s), utc(ep, s.t1_s), color=colour, alpha=0.08, lw=0)
    # The spend as a staircase; with dispersions, each scene's trims' reserve added at its first burn.
    trims = {d.scene: d.trim_p95_km_s * 1000.0 for d in dispersions or () if np.isfinite(d.trim_p95_km_s)}
    firsts = {min(b.t_s for b in s.burns): trims.get(s.index, 0.0) for s in campaign.scenes}
    times = [utc(ep, 0.0)]
    spent = [0.0]
    margin = [0.0]
    for b in campaign.burns:
        times += [utc(ep, b.t_s), utc(ep, b.t_s)]
        spent += [spent[-1], spent[-1] + b.dv_total_km_s * 1000.0]
        margin += [margin[-1], margin[-1] + firsts.get(b.t_s, 0.0)]
    times.append(utc(ep, campaign.duration_s))
    spent.append(spent[-1])
    margin.append(margin[-1])
    ax.plot(times, spent, color="#1f77b4", lw=2, label="Delta-v spent")
    if dispersions:
        top = np.asarray(spent) + np.asarray(margin)
        ax.fill_between(times, spent, top, color="#9467bd", alpha=0.35, lw=0, label="with the trims' 95th percentile")
    ax.axhline(campaign.options.dv_budget_m_s, color="k", ls="--", lw=1, label="budget")
    for s in campaign.scenes:
        t = utc(ep, s.t_access_s)
        ax.axvline(t, color="#ff7f0e", lw=1)
        share = next((d.feasible_share for d in dispersions or () if d.scene == s.index), None)
        ax.annotate(
            f"{s.index}: {s.dv_total_km_s * 1000.0:.0f} m/s" + ("" if share is None else f", {share:.0%} feasible"),
            (t, campaign.options.dv_budget_m_s),
            rotation=90,
            va="top",
            ha="right",
            fontsize=8,
        )
    ax.set_ylabel("Delta-v spent (m/s)")
    ax.set_ylim(0, campaign.options.dv_budget_m_s * 1.05 + 1.0)
    ax.xaxis.set_major_formatter(mdates.DateFormatter("%m-%d"))  # type: ignore[no-untyped-call]
    ax.set_xlabel(f"UTC ({ep:%Y}); green: a stretch that flew a scene, red: one that could not")
    ax.legend(loc="upper left", fontsize=8)
    ax.set_title(f"{len(campaign.scenes)} scene(s), {campaign.dv_total_km_s * 1000.0:.0f} m/s")
    # The line of sight in the target's RTN frame, as azimuth in the along-track/radial plane and elevation off it.
    for s in campaign.scenes:
        los = s.feasibility.line_of_sight_rtn
        if los is None:
            continue
        az = np.degrees(np.arctan2(los[0], los[1]))
        el = np.degrees(np.arcsin(np.clip(los[2], -1.0, 1.0)))
        sky.scatter([az], [el], s=60, color="#ff7f0e", zorder=3)
        sky.annotate(str(s.index), (az, el), xytext=(5, 5), textcoords="offset points")
    sky.set_xlim(-180, 180)
    sky.set_ylim(-90, 90)
    sky.set_xticks(range(-180, 181, 90))
    sky.set_yticks(range(-90, 91, 45))
    sky.grid(alpha=0.3)
    sky.set_xlabel("azimuth from along-track toward radial (deg)")
    sky.set_ylabel("elevation toward the orbit normal (deg)")
    sky.set_title("where the observer sees the target from")
    # Each scene's fly-by as flown, a minute either side of T_access, in the target's orbital frame.
    for s in campaign.scenes:
        rel = s.check.relative if s.check is not None else None
        if rel is None:
            continue
        k0 = int(np.argmin(np.abs(rel.t_s)))
        (line,) = fly.plot(rel.rtn_km[1], rel.rtn_km[0], lw=1.5, label=f"scene {s.index}")
        fly.plot(rel.rtn_km[1][k0], rel.rtn_km[0][k0], "o", mfc="white", mec=line.get_color(), ms=6)
    fly.plot(0.0, 0.0, "ko", ms=6)
    fly.set(
        xlabel="along-track (km; the target moves to the right)",
        ylabel="radial, up (km)",
        title="each scene's fly-by, +-60 s (o: T_access; the target at 0, 0)",
    )
    fly.grid(alpha=0.3)
    if campaign.scenes:
        fly.legend(fontsize=8)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
