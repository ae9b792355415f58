"""gsa plan, gsa access, gsa plans and gsa stations: planning locally or on the service, and their tables."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pydantic import ValidationError

from app.cli.common import (
    EXAMPLE_PLANS,
    EXAMPLES_DIR,
    CliError,
    call_server,
    input_line,
    print_listing,
    read_json,
    resolve_id,
    utc_text,
    validation_line,
)

if TYPE_CHECKING:
    from app.schemas import PlanResult


def cmd_plans(args: argparse.Namespace) -> int:
    from urllib.parse import quote

    from app.schemas import PlanPublic

    if args.plans_cmd == "show":
        body = call_server(
            args, "GET", f"/v1/plans/{quote(resolve_id(args, '/v1/plans', args.id, 'plans'), safe='')}"
        ).json()
        if args.json:
            print(json.dumps(body, indent=2))
        else:
            plan = PlanPublic.model_validate(body)
            print(
                f"plan {plan.id}: {plan.target_name} / {plan.observer_name} / {plan.station_name}, "
                f"created {utc_text(plan.created_at)}"
            )
            print(format_plan(plan))
        return 0

    def row(p: dict[str, Any]) -> str:
        dv = "-" if p.get("dv_total_m_s") is None else f"{p['dv_total_m_s']:9.1f}"
        feasible = "-" if p.get("feasible") is None else "yes" if p["feasible"] else "no"
        return (
            f"{p['id']:<36}  {utc_text(p['created_at']):<24}  {p['target_name'][:16]:<16} {p['observer_name'][:16]:<16} "
            f"{p['station_name'][:14]:<14} {utc_text(p['t_access']):<24} {dv:>9} {feasible:>8}"
        )

    header = (
        f"{'id':<36}  {'created (UTC)':<24}  {'target':<16} {'observer':<16} {'station':<14} {'T_access (UTC)':<24} "
        f"{'dv (m/s)':>9} {'feasible':>8}"
    )
    return print_listing(
        args, "/v1/plans", {"target_name": args.target_name}, "{count} plans; newest {shown}:", header, row
    )


def cmd_stations(args: argparse.Namespace) -> int:
    from urllib.parse import quote

    if args.stations_cmd == "add":
        body = call_server(args, "POST", "/v1/stations", json=read_json(args.file)).json()
        print(f"station {body['name']!r} stored")
        return 0
    if args.stations_cmd == "delete":
        call_server(args, "DELETE", f"/v1/stations/{quote(args.name, safe='')}")
        print(f"station {args.name!r} deleted")
        return 0
    if args.stations_cmd == "show":
        print(json.dumps(call_server(args, "GET", f"/v1/stations/{quote(args.name, safe='')}").json(), indent=2))
        return 0

    def row(st: dict[str, Any]) -> str:
        return (
            f"{st['name'][:24]:<24} {st['latitude_deg']:10.4f} {st['longitude_deg']:10.4f} {st['altitude_m']:8.0f} "
            f"{st['min_elevation_deg']:12.1f} {len(st.get('mask') or []):11d}  {'on' if st['refraction'] else 'off'}"
        )

    header = (
        f"{'name':<24} {'lat (deg)':>10} {'lon (deg)':>10} {'alt (m)':>8} {'min el (deg)':>12} {'mask points':>11}  "
        "refraction"
    )
    return print_listing(args, "/v1/stations", {}, "{count} stations:", header, row)


def cmd_plan(args: argparse.Namespace) -> int:
    from app.errors import InputError
    from app.schemas import PlanCreate, PlanPublic
    from app.services.planning import run_plan, with_radar_of

    if args.export and Path(args.export).exists() and any(Path(args.export).iterdir()):
        raise CliError(f"{args.export} is not empty: give a new or empty directory for --export")
    if args.file and args.example:
        raise CliError("give a request file (the body of POST /v1/plans) or --example paper|iss, not both")
    if not args.file and not args.example:
        raise CliError("give a request file (the body of POST /v1/plans), or --example paper|iss")
    source = args.file or str(EXAMPLES_DIR / EXAMPLE_PLANS[args.example])
    if args.example and not Path(source).is_file():
        raise CliError(f"{source} is missing: the examples live in the repository's examples/ folder")
    if args.server:
        if args.export or args.plot:
            raise CliError("--export and --plot plan locally; with --server, GET /v1/plans/ID/export/... instead")
        body = call_server(args, "POST", "/v1/plans", json=read_json(source), timeout=600).json()
        if args.json:
            print(json.dumps(body, indent=2))
        else:
            answer = PlanPublic.model_validate(body)
            print(f"plan {answer.id} stored\n" + format_plan(answer))
        return 0
    try:
        req = PlanCreate.model_validate(read_json(source))
        plan, result = run_plan(req)
    except ValidationError as exc:
        raise CliError(validation_line(exc, PlanCreate)) from None
    except InputError as exc:
        raise CliError(input_line(exc)) from None
    req = with_radar_of(req, plan.station.name if plan.station is not None else None)
    assert req.ground_station is not None and not isinstance(req.ground_station, str)  # only the server resolves names
    if args.json:
        print(json.dumps(result.model_dump(mode="json"), indent=2))
    else:
        print(format_plan(result))
    if args.export:
        _export_plan(plan, result.model_dump(mode="json"), req, Path(args.export))
    if args.plot:
        from planner.plot import plot_plan

        plot_plan(plan, args.plot, title=f"{req.target.name} / {req.observer.name} / {req.ground_station.name}")
        print(f"plot written to {args.plot}", file=sys.stderr)
    return 0


FILE_NAMES = {  # an export's stored name -> its file in --export's folder
    "opm": "opm.txt",
    "opm.xml": "opm.xml",
    "oem": "oem.txt",
    "oem.xml": "oem.xml",
    "czml": "plan.czml",
    "geojson": "plan.geojson",
    "pointing.csv": "pointing.csv",
}


def _export_plan(plan: Any, result: dict[str, Any], req: Any, folder: Path) -> None:
    """Write the plan in every export format into ``folder`` (as GET /v1/plans/{id}/export/... serves them)."""
    from app.services import exports
    from app.services.planning import access_csv, scenes_by_pass

    folder.mkdir(parents=True, exist_ok=True)
    names = {"target": req.target.name, "observer": req.observer.name, "station": req.ground_station.name}
    texts = exports.with_later(
        exports.render(plan, result, plan_id="local", names=names, station=req.ground_station.model_dump())
    )
    if not result.get("phasing"):
        print("note: no OPM, OEM or CZML: the plan has no phasing burn (no candidate was planned)", file=sys.stderr)
    files = {"access.csv": access_csv(result["access_windows"], scenes_by_pass(result))} | {
        FILE_NAMES[k]: v for k, v in texts.items()
    }
    for fname, body in files.items():
        (folder / fname).write_text(body)
    print(f"wrote {', '.join(sorted(files))} to {folder}", file=sys.stderr)


def cmd_access(args: argparse.Namespace) -> int:
    from app.errors import InputError
    from app.schemas import AccessCreate
    from app.services.planning import run_access

    try:
        req = AccessCreate.model_validate(read_json(args.file))
        if req.targets is not None:
            return _catalogue(req, args.workers)
        result = run_access(req)
    except ValidationError as exc:
        raise CliError(validation_line(exc, AccessCreate)) from None
    except InputError as exc:
        raise CliError(input_line(exc)) from None
    body = result.model_dump(mode="json")
    print(json.dumps(body, indent=2) if args.json else format_windows(body["access_windows"]))
    return 0


def _catalogue(req: Any, workers: int) -> int:
    """A catalogue's windows on standard output, shard by shard, in the service's bytes: the shards on ``workers``
    processes here, or as Ray tasks on the cluster at GSA_RAY_ADDRESS (the order kept, so the same bytes either
    way). Over the budget (GSA_ACCESS_BUDGET) it is refused as the service refuses it."""
    from app.core.config import get_settings
    from app.errors import TooLarge
    from app.services.catalogue import prepare, stream
    from inference.engine import EngineError, engine_for

    if workers < 1:
        raise CliError("--workers must be at least 1")
    try:
        cat = prepare(req, get_settings().access_budget)
    except TooLarge as exc:
        raise CliError(str(exc)) from None
    try:
        engine = engine_for(workers=workers)
    except EngineError as exc:
        raise CliError(str(exc)) from None
    for piece in stream(cat, engine.map):
        sys.stdout.write(piece)
    sys.stdout.flush()
    return 0


def format_windows(windows: list[dict[str, Any]]) -> str:
    lines = [
        f"{'rise (UTC)':<25} {'culmination (UTC)':<25} {'set (UTC)':<25} {'max el (deg)':>12} "
        f"{'min range (km)':>14} {'duration (s)':>12}"
    ]
    for w in windows:
        lines.append(
            f"{utc_text(w['rise']):<25} {utc_text(w['culmination']):<25} {utc_text(w['set']):<25} "
            f"{w['max_elevation_deg']:12.2f} {w['min_range_km']:14.1f} {w['duration_s']:12.1f}"
        )
    return "\n".join(lines)


def format_plan(r: PlanResult) -> str:
    """Return a plan as a readable report: every time in UTC with Z, every number with its unit."""
    out = [f"epoch {utc_text(r.epoch)}, {r.duration_days:g} days, elements read as {r.reading}"]
    out.append(f"\n{len(r.access_windows)} access windows")
    out.append(format_windows([w.model_dump(mode="json") for w in r.access_windows[:10]]))
    if len(r.access_windows) > 10:
        out.append(f"... and {len(r.access_windows) - 10} more")
    out.append(
        f"\n{len(r.candidates)} candidates (best of each pass, ranked by miss; every one shown); * marks the chosen one"
    )
    out.append(
        f"{'#':>4} {'T_access (UTC)':<25} {'dHa (km)':>9} {'dHp (km)':>9} {'miss (km)':>10} {'node':>5} "
        f"{'dv (m/s)':>9} {'stand-off (km)':>14} {'rate (deg/s)':>12} {'sunlit':>7} "
        f"{'radar el (deg)':>14} {'SNR (dB)':>8} {'T_int (s)':>9}  feasible"
    )
    chosen_at = None if r.chosen is None else r.chosen.t_access

    def fixed(v: float | None, width: int, digits: int) -> str:
        return f"{'-':>{width}}" if v is None else f"{v:{width}.{digits}f}"

    for k, c in enumerate(r.candidates):
        f = c.feasibility
        mark = "*" if c.t_access == chosen_at else " "
        verdict = "yes" if f.feasible else "no: " + "; ".join(f.reasons)
        out.append(
            f"{mark}{k:3d} {utc_text(c.t_access):<25} {c.delta_ha_km:9.1f} {c.delta_hp_km:9.1f} "
            f"{c.miss_km:10.3f} {c.node:>5} {fixed(c.dv_total_m_s, 9, 1)} {fixed(c.standoff_km, 14, 1)} "
            f"{fixed(f.target_angular_rate_deg_s, 12, 2)} {('yes' if f.sunlit else 'no'):>7} "
            f"{fixed(f.radar_elevation_deg, 14, 1)} {fixed(f.radar_snr_db, 8, 1)} {fixed(f.isar_integration_s, 9, 1)}  "
            + (f"[{c.station}] " if c.station else "")
            + f"{verdict}"
        )
    ch = r.chosen
    if ch:
        out.append(
            f"\nchosen: T_access {utc_text(ch.t_access)}, dHa {ch.delta_ha_km:.1f} km, dHp {ch.delta_hp_km:.1f} km"
        )
        out.append(f"  node-line miss with the changed observer's own propagation: {ch.miss_km:.3f} km")
        out.append(f"  height change costs {r.alignment_dv_m_s:.1f} m/s")
    ph = r.phasing
    if ph:
        v = ph.verification
        out.append(
            f"phasing: burn {utc_text(ph.t_burn)} ({ph.revolutions_before} rev before), "
            f"dv {ph.dv_total_m_s:.1f} m/s, RTN [{', '.join(f'{x:.1f}' for x in ph.dv_rtn_m_s)}] m/s"
        )
        out.append(
            f"verification (numerical J2): {v.miss_km * 1000:.1f} m from the aim point at T_access "
            f"(two-body Lambert alone: {v.two_body_miss_km:.1f} km), relative speed {v.relative_speed_km_s:.2f} km/s"
        )
        out.append(
            f"encounter: stand-off {v.standoff_km:.2f} km, separation {v.separation_km:.3f} km at T_access, "
            f"closest approach {v.closest_approach_km:.3f} km at {utc_text(v.closest_approach_time)}, "
            f"target angular rate {v.target_angular_rate_deg_s:.2f} deg/s"
        )
    if ch:
        f = ch.feasibility
        if f.radar_elevation_deg is not None:
            out.append(
                f"radar: elevation {f.radar_elevation_deg:.1f} deg, range {f.radar_range_km or 0.0:.0f} km, "
                f"integration {f.isar_integration_s or 0.0:.1f} s"
                + (
                    ""
                    if f.radar_snr_db is None
                    else f", SNR {f.radar_snr_db:.1f} dB (cross section {f.radar_cross_section_m2 or 0.0:.3g} m^2)"
                )
            )
        out.append(f"feasible: {'yes' if f.feasible else 'no'}" + (f" ({'; '.join(f.reasons)})" if f.reasons else ""))
    for note in r.notes:
        out.append(f"note: {note}")
    return "\n".join(out)


EXAMPLE_CAMPAIGNS = {"paper": "paper-campaign.json"}


def cmd_campaign(args: argparse.Namespace) -> int:
    from app.errors import InputError
    from app.schemas import CampaignCreate
    from app.services.campaigns import run_campaign
    from app.services.planning import with_radar_of

    if args.file == "replan":
        return _replan_campaign(args)
    if args.replan_args:
        raise CliError(f"unexpected {' '.join(args.replan_args)!r}: give one request file, or replan ID FILE")
    if args.export and Path(args.export).exists() and any(Path(args.export).iterdir()):
        raise CliError(f"{args.export} is not empty: give a new or empty directory for --export")
    if args.file and args.example:
        raise CliError("give a request file (the body of POST /v1/campaigns) or --example paper, not both")
    if not args.file and not args.example:
        raise CliError("give a request file (the body of POST /v1/campaigns), or --example paper")
    source = args.file or str(EXAMPLES_DIR / EXAMPLE_CAMPAIGNS[args.example])
    if args.server:
        if args.export or args.plot:
            raise CliError("--export and --plot plan locally; with --server, GET /v1/campaigns/ID/export/... instead")
        from app.cli.jobs import submit

        _print_stored_campaign(args, submit(args, "/v1/campaigns", json=read_json(source), timeout=120))
        return 0

    shown = []

    def progress(fraction: float, what: str) -> None:  # on a terminal only: one line, rewritten
        if sys.stderr.isatty():
            shown.append(fraction)
            print(f"\r{fraction * 100:5.1f} % of the span searched, {what}", end="", file=sys.stderr, flush=True)

    try:
        req = CampaignCreate.model_validate(read_json(source))
        campaign, result = run_campaign(req, progress=progress)
    except ValidationError as exc:
        raise CliError(validation_line(exc, CampaignCreate)) from None
    except InputError as exc:
        raise CliError(input_line(exc)) from None
    finally:
        if shown:
            print(file=sys.stderr)
    first = campaign.scenes[0].plan.station if campaign.scenes else None
    req = with_radar_of(req, first.name if first is not None else None)
    assert req.ground_station is not None and not isinstance(req.ground_station, str)  # only the server resolves names
    print(json.dumps(result.model_dump(mode="json"), indent=2) if args.json else format_campaign(result))
    if args.export:
        _export_campaign(req, result, Path(args.export))
    if args.plot:
        from planner.dispersion import SceneDispersion
        from planner.plot import plot_campaign

        nan = float("nan")
        dispersions = [
            SceneDispersion(
                sc.index,
                d.samples,
                d.feasible_share,
                nan if d.trim_p95_m_s is None else d.trim_p95_m_s / 1000.0,
                nan if d.trim_max_m_s is None else d.trim_max_m_s / 1000.0,
                nan if d.miss_p95_km is None else d.miss_p95_km,
                sc.aim.tolerance_km if sc.aim else nan,
                d.failed,
            )
            for sc in result.scenes
            if (d := sc.dispersion) is not None
        ]
        title = f"{req.target.name} / {req.observer.name} / {req.ground_station.name}"
        plot_campaign(campaign, args.plot, title=title, dispersions=dispersions or None)
        print(f"plot written to {args.plot}", file=sys.stderr)
    return 0


def _replan_campaign(args: argparse.Namespace) -> int:
    """``gsa campaign replan ID FILE``: re-plan a stored campaign on the service from FILE's observer and time."""
    from urllib.parse import quote

    if len(args.replan_args) != 2:
        raise CliError('give replan ID FILE: the stored campaign\'s id and {"observer": ..., "from": ...} as JSON')
    if not args.server:
        raise CliError("replan acts on a campaign stored on the service: give --server URL (or set GSA_SERVER)")
    if args.export or args.plot or args.example:
        raise CliError("replan takes no --example, --export or --plot: GET /v1/campaigns/NEW_ID/export/... instead")
    campaign_id, source = args.replan_args
    body = call_server(
        args, "POST", f"/v1/campaigns/{quote(campaign_id, safe='')}/replan", json=read_json(source), timeout=900
    ).json()
    _print_stored_campaign(args, body, f", re-planned from {campaign_id}")
    return 0


def _print_stored_campaign(args: argparse.Namespace, body: dict[str, Any], note: str = "") -> None:
    """A campaign the service stored, as JSON with --json or as the report."""
    from app.schemas import CampaignPublic

    if args.json:
        print(json.dumps(body, indent=2))
        return
    answer = CampaignPublic.model_validate(body)
    print(f"campaign {answer.id} stored{note}\n" + format_campaign(answer))


def _export_campaign(req: Any, result: Any, folder: Path) -> None:
    """Write the campaign in every export format into ``folder`` (as GET /v1/campaigns/{id}/export/... serves them)."""
    from types import SimpleNamespace

    from app.services import campaign_exports

    folder.mkdir(parents=True, exist_ok=True)
    row = SimpleNamespace(
        id="local",
        request=req.model_dump(mode="json"),
        result=result.stored(),
        target_name=req.target.name,
        observer_name=req.observer.name,
        station_name=req.ground_station.name,
    )
    files = {name: campaign_exports.export(kind, row) for kind, name in campaign_exports.EXPORT_FILES.items()}
    for fname, body in files.items():
        (folder / fname).write_text(body)
    print(f"wrote {', '.join(sorted(files))} to {folder}", file=sys.stderr)


def cmd_campaigns(args: argparse.Namespace) -> int:
    from urllib.parse import quote

    from app.schemas import CampaignPublic

    if args.campaigns_cmd == "show":
        body = call_server(
            args, "GET", f"/v1/campaigns/{quote(resolve_id(args, '/v1/campaigns', args.id, 'campaigns'), safe='')}"
        ).json()
        if args.json:
            print(json.dumps(body, indent=2))
        else:
            c = CampaignPublic.model_validate(body)
            print(
                f"campaign {c.id}: {c.target_name} / {c.observer_name} / {c.station_name}, "
                f"created {utc_text(c.created_at)}"
            )
            print(format_campaign(c))
        return 0

    def row(c: dict[str, Any]) -> str:
        return (
            f"{c['id']:<36}  {utc_text(c['created_at']):<24}  {c['target_name'][:16]:<16} {c['observer_name'][:16]:<16} "
            f"{c['station_name'][:14]:<14} {c['scenes']:>6} {c['dv_total_m_s']:>9.1f}  {utc_text(c['first_access'])}"
        )

    header = (
        f"{'id':<36}  {'created (UTC)':<24}  {'target':<16} {'observer':<16} {'station':<14} {'scenes':>6} "
        f"{'dv (m/s)':>9}  first T_access (UTC)"
    )
    return print_listing(
        args, "/v1/campaigns", {"target_name": args.target_name}, "{count} campaigns; newest {shown}:", header, row
    )


def format_campaign(r: Any) -> str:
    """Return a campaign (CampaignResult) as a readable report: its scenes, their burns, and every stretch."""
    margin = getattr(r, "trim_margin_m_s", None)
    out = [
        f"epoch {utc_text(r.epoch)}, {r.duration_days:g} days, budget {r.dv_budget_m_s:g} m/s, "
        f"return to orbit: {'yes' if r.return_to_orbit else 'no'}"
        + (f", re-planned from campaign {r.replanned_from}" if r.replanned_from else ""),
        f"\n{len(r.scenes)} scene(s), {r.dv_total_m_s:.1f} m/s in all"
        + ("" if margin is None else f", {margin:.1f} m/s kept for the trims (95th percentile)"),
        f"{'#':>3} {'T_access (UTC)':<25} {'dv (m/s)':>9} {'stand-off (km)':>14} {'separation (km)':>15} "
        f"{'rate (deg/s)':>12} {'phase (deg)':>11}  line of sight (R, T, N)",
    ]
    for s in r.scenes:
        c = s.check
        los = s.candidate.feasibility.line_of_sight_rtn or []
        out.append(
            f"{s.index:3d} {utc_text(s.t_access):<25} {s.dv_total_m_s:9.1f} {s.candidate.standoff_km or 0.0:14.1f} "
            f"{c.separation_km:15.2f} {c.target_angular_rate_deg_s:12.2f} {c.phase_angle_deg:11.1f}  "
            f"({', '.join(f'{x:+.2f}' for x in los)})"
            + (f"  radar {s.candidate.station}" if s.candidate.station else "")
        )
        for b in s.burns:
            out.append(
                f"      {b.kind:<8} {utc_text(b.time)}  {b.dv_total_m_s:8.1f} m/s  RTN "
                f"[{', '.join(f'{x:.1f}' for x in b.dv_rtn_m_s)}]"
            )
        if s.aim is not None:
            out.append(
                f"      aim: RTN of the target [{', '.join(f'{x:.2f}' for x in s.aim.relative_rtn_km)}] km at T_access, "
                f"within {s.aim.tolerance_km:.2f} km{' (re-aimed)' if s.reaimed else ''}"
            )
        if s.dispersion is not None:
            d = s.dispersion
            out.append(
                f"      with errors ({d.samples} samples): {d.feasible_share:.0%} feasible, trims p95 "
                f"{d.trim_p95_m_s or 0.0:.1f} m/s, miss p95 {d.miss_p95_km or 0.0:.3f} km"
            )
    out.append("\nstretches searched")
    for st in r.stretches:
        out.append(
            f"  {utc_text(st.start)} .. {utc_text(st.end)}: {st.candidates} candidates, {st.feasible} feasible; {st.note}"
        )
    for note in r.notes:
        out.append(f"note: {note}")
    return "\n".join(out)
