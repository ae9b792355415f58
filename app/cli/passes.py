"""gsa simulate --pass and gsa pass: a simulated pass over a plan's station, and its frames fused."""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from datetime import datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pydantic import ValidationError

from app.cli.common import (
    CliError,
    call_server,
    input_line,
    load_settings,
    local_models,
    read_json,
    resolve_id,
    validation_line,
)

if TYPE_CHECKING:
    from app.schemas import PassResult


def add_pass_arguments(p: argparse.ArgumentParser) -> None:
    """``gsa simulate --pass``: the frames of one radar pass instead of a data set."""
    g = p.add_argument_group("a radar pass (--pass REQUEST.json): the frames the station's radar forms over one pass")
    g.add_argument(
        "--pass",
        dest="pass_request",
        metavar="REQUEST.json",
        help="a plan request (the body of POST /v1/plans): its target over one of its access windows to its "
        "station; with --out DIR writes DIR/frames.npz, DIR/pass.json and DIR/frames.png",
    )
    g.add_argument(
        "--scene",
        metavar="PLAN_ID|REQUEST.json",
        help="labelled frames of a planned GSA scene, for gsa adapt: a stored plan (its id, from this machine's "
        "database) or a plan request file; the pass's frames rendered with --physics (a stand-in for your radar) "
        "and labelled by the optical observer's attitude, off by --label-error-deg; --out DIR gets one .npz a "
        "frame (inference.labelled's format), scene.json and frames.png",
    )
    g.add_argument(
        "--label-error-deg",
        type=float,
        default=0.2,
        help="with --scene: the optical attitude's error, 1-sigma per axis (default 0.2 deg)",
    )
    g.add_argument("--window", type=int, help="which of the plan's access windows (default: the highest)")
    g.add_argument("--frames", type=int, default=60, help="at most this many frames, thinned evenly (default 60)")
    g.add_argument(
        "--step-deg", type=float, help="between frame centres, in line-of-sight sweep (default: the aperture)"
    )
    g.add_argument(
        "--attitude-lvlh",
        metavar="Z,Y,X",
        help="the target's attitude, body to LVLH, deg (default: drawn so mid-pass looks within --max-angle-deg)",
    )
    g.add_argument(
        "--spin-deg-s", type=float, default=0.0, help="spin about --spin-axis (deg/s, default 0: still in LVLH)"
    )
    g.add_argument("--spin-axis", default="0,0,1", metavar="X,Y,Z", help="the spin's body axis (default 0,0,1)")
    g.add_argument(
        "--snr-reference",
        metavar="DB@KM",
        help="SNR from range by the radar equation: DB at KM, falling as range to the fourth power",
    )
    g.add_argument(
        "--within-deg",
        type=float,
        help="keep only frames whose observation-frame angles are within this (the networks' range: 45)",
    )


def pass_or_data_set(data_set: Any) -> Any:
    """``gsa simulate``: a pass with --pass, a scene's labelled frames with --scene, else the data set command."""

    def command(args: argparse.Namespace) -> int:
        if args.pass_request and args.scene:
            raise CliError("give --pass or --scene, not both")
        if args.scene:
            return cmd_simulate_scene(args)
        return cmd_simulate_pass(args) if args.pass_request else int(data_set(args))

    return command


def _floats(text: str, n: int, flag: str) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != n or not all(math.isfinite(v) for v in values):
        raise CliError(f"{flag} {text!r}: write {n} numbers separated by commas")
    return values


def _plan_for_pass(request: Any) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """A plan request, checked, and its target's access windows to its station over the request's span."""
    from app.errors import InputError
    from app.schemas import AccessCreate, PlanCreate
    from app.services.planning import run_access

    try:
        req = PlanCreate.model_validate(request)
        if req.ground_station is None:
            raise CliError("a pass is over one radar: give ground_station, not ground_stations")
        acc = AccessCreate(
            target=req.target,
            ground_station=req.ground_station,
            start=req.search.start,
            duration_days=req.search.duration_days,
            reading=req.search.reading,
        )
        windows = run_access(acc).model_dump(mode="json")["access_windows"]
    except ValidationError as exc:
        raise CliError(validation_line(exc, PlanCreate)) from None
    except InputError as exc:
        raise CliError(input_line(exc)) from None
    return req.model_dump(mode="json", exclude_none=True), windows


def _scattering(args: argparse.Namespace) -> Any:
    """The stand-in physics of a simulated pass: the data set command's --physics options, one frame's worth."""
    from inference.simulation.dataset import parse_roughness
    from inference.simulation.scene import DEFAULT_SCATTERING, Scattering

    if getattr(args, "physics", "centres") != "po":
        return DEFAULT_SCATTERING
    lo, hi = parse_roughness(args.roughness)
    if hi > lo:
        raise CliError(f"--roughness {args.roughness}: a pass takes one roughness, not a range")
    return Scattering(physics="po", bounces=args.bounces, roughness=lo, facet_m=args.facet_m)


def _simulated_pass(args: argparse.Namespace, request_source: Any, out: Path) -> tuple[Any, ...]:
    """Simulate and render a pass of ``request_source`` (a plan request); return what both commands write."""
    import numpy as np

    from app.errors import DOMAIN_ERRORS
    from app.services.scenes import scene_for, windows_of
    from inference.simulation.dataset import parse_snr
    from inference.simulation.radar import Radar
    from scene import choose_window
    from scene.simulation import PassOptions, render_pass, simulate_pass

    if out.exists():
        raise CliError(f"{out} exists: give a new directory")
    lo, hi = parse_snr(args.snr_db)
    ref = None
    if args.snr_reference:
        db, sep, km = args.snr_reference.partition("@")
        try:
            ref = (float(db), float(km))
        except ValueError:
            raise CliError(f"--snr-reference {args.snr_reference!r}: write DB@KM, e.g. 12@800") from None
        if not sep or not all(math.isfinite(v) for v in ref) or ref[1] <= 0:
            raise CliError(f"--snr-reference {args.snr_reference!r}: write DB@KM with KM over 0, e.g. 12@800")
    try:
        radar = Radar(args.carrier_hz, args.bandwidth_hz, args.n_range, args.n_azimuth, args.aperture_deg)
        scattering = _scattering(args)
        request, windows = _plan_for_pass(request_source)
        opts = PassOptions(
            window=args.window,
            aperture_deg=args.aperture_deg,
            step_deg=args.step_deg,
            max_frames=args.frames,
            attitude_lvlh_deg=_floats(args.attitude_lvlh, 3, "--attitude-lvlh") if args.attitude_lvlh else None,  # type: ignore[arg-type]
            max_angle_deg=min(args.max_angle_deg, 89.0),
            spin_deg_s=args.spin_deg_s,
            spin_axis=_floats(args.spin_axis, 3, "--spin-axis"),  # type: ignore[arg-type]
            snr_db=None if lo is None or hi is None else (lo, hi),
            snr_reference=ref,
            within_deg=args.within_deg,
            seed=args.seed,
        )
        index, chosen = choose_window(windows_of({"access_windows": windows}), opts.window)
        window = windows[index]
        rng = np.random.default_rng(opts.seed)
        scene = scene_for(request, chosen.rise, chosen.set, field="window")
        meta = simulate_pass(scene, opts, rng)
        model = None
        if args.model:
            from inference.simulation.dataset import DatasetSpec, build_model

            model = build_model(DatasetSpec(n=1, model_path=args.model, model_scale=args.model_scale), radar)
        print(
            f"window {index}: {window['rise']} to {window['set']}, culminating at "
            f"{window['max_elevation_deg']:.1f} deg; rendering {len(meta)} frames"
            + (" by physical optics" if scattering.physics == "po" else ""),
            file=sys.stderr,
        )
        images, snrs = render_pass(meta, opts, rng, radar, model, scattering)
    except DOMAIN_ERRORS as exc:
        raise CliError(input_line(exc)) from None
    return meta, images, snrs, opts, index, window, request, radar, rng


def cmd_simulate_pass(args: argparse.Namespace) -> int:
    import numpy as np

    from app.services.passes import pass_record
    from inference.rotations import reversed_reading

    if not args.out:
        raise CliError("give --out DIR for the pass's frames")
    out = Path(args.out)
    meta, images, snrs, opts, index, window, request, radar, _ = _simulated_pass(
        args, read_json(args.pass_request), out
    )
    record = pass_record(meta, snrs, opts, index, window, request, (radar.range_cell_m, radar.cross_range_cell_m))
    partial = out.with_name(out.name + ".partial")
    partial.mkdir(parents=True, exist_ok=False)
    np.savez_compressed(partial / "frames.npz", image=images.astype(np.float32))
    (partial / "pass.json").write_text(json.dumps(record, indent=1))
    _contact_sheet(images, record, partial / "frames.png")
    partial.rename(out)
    seen = [f["attitude_observation"]["euler_zyx_deg"] for f in record["frames"]]
    inside = sum(max(abs(a) for a in angles) <= 45.0 for angles in seen)
    # A target turning against the line of sight faster than it sweeps is read reversed in cross-range.
    reversed_ = sum(max(abs(a) for a in reversed_reading(angles)) <= 45.0 for angles in seen)
    print(
        f"{len(meta)} frames in {out} ({inside} within the networks' 45 deg range"
        + (f", {reversed_} more read reversed in cross-range" if reversed_ else "")
        + "); upload frames.npz with normalised=true and each frame's observed_at from pass.json"
    )
    return 0


CAMPAIGN_SCENE_HALF_SPAN_S = 1800.0  # a campaign scene's pass: the access search half an hour either side of T_access


def _stored_plan_request(plan_id: str) -> tuple[dict[str, Any], str]:
    """A plan stored in this machine's database (the service's, GSA_DATABASE_URL): its request and its id.

    A campaign's id (``ID`` for its first scene, ``ID:K`` for scene K) gives a plan request of its target, observer
    and station over the hour about that scene's T_access, so the pass simulated is the scene's."""
    from sqlalchemy.exc import SQLAlchemyError

    from app.cli.common import open_session
    from app.db.models import Campaign, Plan

    ident, _, k_text = plan_id.partition(":")
    try:
        with open_session() as session:
            plan = session.get(Plan, ident) if not k_text else None
            request = None if plan is None else (dict(plan.request), plan.id)
            campaign = session.get(Campaign, ident) if request is None else None
            if campaign is not None:
                request = _campaign_scene_request(campaign.request, campaign.result, campaign.id, k_text)
    except SQLAlchemyError as exc:
        raise CliError(
            f"{plan_id}: no such file, and this machine's database cannot be read for plans "
            f"({type(exc).__name__}; run gsa db upgrade, or give a plan request file)"
        ) from None
    if request is None:
        raise CliError(
            f"{plan_id}: no such plan or campaign in this machine's database, and no such file; give a plan id "
            "(gsa plans list), a campaign id (gsa campaigns list; ID:K for its scene K) or a plan request file"
        )
    return request


def _campaign_scene_request(
    request: dict[str, Any], result: dict[str, Any], campaign_id: str, k_text: str
) -> tuple[dict[str, Any], str]:
    from datetime import datetime, timedelta

    scenes = result.get("scenes") or []
    if not scenes:
        raise CliError(f"campaign {campaign_id} flew no scene: there is no pass of it to simulate")
    try:
        k = int(k_text) if k_text else 0
    except ValueError:
        raise CliError(f"{campaign_id}:{k_text}: write the scene's number, 0 to {len(scenes) - 1}") from None
    if not 0 <= k < len(scenes):
        raise CliError(f"campaign {campaign_id} has scenes 0 to {len(scenes) - 1}; {k} is not one of them")
    t_access = datetime.fromisoformat(scenes[k]["t_access"].replace("Z", "+00:00"))
    start = t_access - timedelta(seconds=CAMPAIGN_SCENE_HALF_SPAN_S)
    plan_like = {key: request[key] for key in ("target", "observer", "ground_station")}
    plan_like["search"] = {
        "start": start.isoformat(),
        "duration_days": 2 * CAMPAIGN_SCENE_HALF_SPAN_S / 86400.0,
    }
    return plan_like, f"{campaign_id}-scene-{k}"


def cmd_simulate_scene(args: argparse.Namespace) -> int:
    """``gsa simulate --scene``: a planned scene's frames in the labelled-frame format, labelled by the observer."""
    import numpy as np

    from app.services.passes import pass_record
    from inference.labelled import write_frame
    from scene.labels import optical_attitudes

    if not args.out:
        raise CliError("give --out DIR for the scene's labelled frames")
    if not (0.0 <= args.label_error_deg <= 10.0) or not math.isfinite(args.label_error_deg):
        raise CliError(f"--label-error-deg {args.label_error_deg}: between 0 and 10 deg")
    out = Path(args.out)
    source = Path(args.scene)
    if source.is_file():
        request_source, name = read_json(str(source)), source.stem
    else:
        request_source, name = _stored_plan_request(args.scene)
    meta, images, snrs, opts, index, window, request, radar, rng = _simulated_pass(args, request_source, out)
    quats, labels = optical_attitudes(meta, args.label_error_deg, rng)
    scene_name = f"{name}-window-{index}"
    partial = out.with_name(out.name + ".partial")
    partial.mkdir(parents=True, exist_ok=False)
    for k, f in enumerate(meta):
        write_frame(
            partial / f"frame-{k:03d}.npz",
            images[k].astype(np.float32),
            angles_deg=labels[k],
            quaternion_j2000=quats[k],
            observed_at=f.observed_at,
            scene=scene_name,
            attitude_sigma_deg=args.label_error_deg,
            snr_db=float(snrs[k]),
            normalised=True,
        )
    record = pass_record(meta, snrs, opts, index, window, request, (radar.range_cell_m, radar.cross_range_cell_m))
    record["scene"] = scene_name
    record["label_error_deg"] = args.label_error_deg
    record["physics"] = _scattering(args).physics
    (partial / "scene.json").write_text(json.dumps(record, indent=1))
    _contact_sheet(images, record, partial / "frames.png")
    partial.rename(out)
    inside = int(np.sum(np.all(np.abs(labels) <= 45.0, axis=1)))
    print(
        f"{len(meta)} labelled frames of scene {scene_name} in {out} ({inside} within the networks' 45 deg range); "
        f"adapt with: gsa adapt --frames {out} --out MODELS"
    )
    return 0


def _contact_sheet(images: Any, record: dict[str, Any], path: Path, most: int = 12) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    pick = np.unique(np.linspace(0, len(images) - 1, min(most, len(images))).round().astype(int))
    cols = min(6, len(pick))
    rows = -(-len(pick) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(2.2 * cols, 2.75 * rows), squeeze=False)
    for ax in axes.ravel():
        ax.axis("off")
    for ax, k in zip(axes.ravel(), pick, strict=False):
        f = record["frames"][k]
        z, y, x = f["attitude_observation"]["euler_zyx_deg"]
        ax.imshow(images[k], cmap="gray", vmin=0, vmax=1)
        snr = "noise-free" if f["snr_db"] is None else f"{f['snr_db']:.0f} dB"
        ax.set_title(f"{f['observed_at'][11:19]}Z, {snr}\n{z:.0f} / {y:.0f} / {x:.0f} deg", fontsize=7)
    w = record["window"]
    fig.suptitle(
        f"pass {w['rise'][:19]} to {w['set'][11:19]} UTC, max elevation {w['max_elevation_deg']:.0f} deg "
        "(frame time, SNR, attitude in its observation frame)",
        fontsize=9,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def cmd_pass(args: argparse.Namespace) -> int:
    """Fuse a simulated (or any) pass: each frame estimated and fitted, placed in LVLH, fused."""

    from app.errors import DOMAIN_ERRORS
    from app.schemas import PassResult

    folder = Path(args.folder)
    rec = read_json(str(folder / "pass.json"))
    try:
        data = (folder / "frames.npz").read_bytes()
    except OSError as exc:
        raise CliError(f"cannot read {folder / 'frames.npz'}: {exc.strerror}") from None
    try:
        times = [datetime.fromisoformat(f["observed_at"]) for f in rec["frames"]]
    except (KeyError, TypeError, ValueError):
        raise CliError(
            f"{folder / 'pass.json'} has no frames with an observed_at each (write it with gsa simulate --pass)"
        ) from None
    if args.server:
        return _pass_on_server(args, data, rec)
    from app.services import uploads as upload_svc
    from app.services.estimation import prepare_frames
    from app.services.scenes import scene_for
    from scene.fusion import fit_and_fuse, pass_span, sweeps_from

    settings = load_settings()
    request = rec.get("plan_request")
    if args.plan:
        request, _ = _plan_for_pass(read_json(args.plan))
    if request is None:
        raise CliError("give --plan PLAN.json: the pass record names no plan")
    try:
        est, checker = local_models(args, settings)
        uploads = upload_svc.decode(data, "frames.npz")
        if len(uploads) != len(times):
            raise CliError(f"frames.npz holds {len(uploads)} frames and pass.json {len(times)} times")
        integration, aperture = _integration(rec)
        sweeps = sweeps_from(integration, aperture, len(times), checker.radar.aperture_deg)
        frames, prep_s = prepare_frames(
            est=est, checker=checker, uploads=uploads, resample=False, normalised=True, cells_m=None
        )
        fused = fit_and_fuse(
            est=est,
            checker=checker,
            frames=frames,
            scene=scene_for(request, *pass_span(times, sweeps)),
            observed_at=times,
            names=[f"frame {k}" for k in range(len(times))],
            sweeps=sweeps,
            preprocess_s=prep_s,
            progress=pass_progress(sys.stderr),
        )
        result = PassResult.from_pass(fused.attitude, target=checker.model.name, timings_s=fused.timings_s)
    except DOMAIN_ERRORS as exc:
        raise CliError(input_line(exc)) from None
    if args.json:
        print(json.dumps(result.model_dump(mode="json"), indent=1))
    else:
        _print_pass(result, rec)
        print(f"{len(times)} frames: estimated and fitted in {fused.fit_s:.1f} s, fused in {fused.fuse_s:.1f} s")
    if args.plot:
        _plot_pass(result, rec, args.plot)
        print(f"plot written to {args.plot}", file=sys.stderr)
    return 0


def pass_progress(stream: Any, width: int = 30) -> Any:
    """A progress bar for ``fit_and_fuse`` on ``stream`` when it is a terminal (one line, rewritten), else nothing.

    The networks read the whole pass at once ("estimated"), the fit goes frame by frame ("fitted k/N"),
    then the fusion ("fused"); the line ends when the pass is fused.
    """
    if not stream.isatty():
        return None
    t0 = time.perf_counter()

    def show(stage: str, done: int, total: int) -> None:
        # the networks count for a tenth of the bar, the fit for the rest up to the fusion
        share = {"estimated": 0.1, "fitted": 0.1 + 0.85 * done / max(total, 1), "fused": 1.0}[stage]
        bar = "#" * round(width * share)
        what = {"estimated": f"{total} frames estimated", "fitted": f"{done}/{total} fitted", "fused": "fused"}[stage]
        end = "\n" if stage == "fused" else ""
        print(f"\r[{bar:<{width}}] {what}, {time.perf_counter() - t0:.0f} s   ", end=end, file=stream, flush=True)

    return show


def _integration(rec: dict[str, Any]) -> tuple[list[float] | None, float | None]:
    """The pass record's integration times (every frame's, or None) and the aperture its frames integrate."""
    times = [f.get("integration_s") for f in rec["frames"]]
    if not times or any(t is None for t in times):
        return None, None
    aperture = (rec.get("options") or {}).get("aperture_deg")
    return times, aperture


def _pass_on_server(args: argparse.Namespace, data: bytes, rec: dict[str, Any]) -> int:

    if not args.plan_id:
        explicit = any(a == "--server" or a.startswith("--server=") for a in sys.argv[1:])
        via = "--server" if explicit else "GSA_SERVER (set in the environment)"
        raise CliError(
            f"a pass sent to the service ({via}) needs --plan-id: the stored plan the pass belongs to; "
            "unset GSA_SERVER to fuse it locally"
        )
    form: dict[str, Any] = {
        "plan_id": args.plan_id,
        "normalised": "true",
        "observed_at": [f["observed_at"] for f in rec["frames"]],
    }
    integration, aperture = _integration(rec)
    if integration is not None:
        form["integration_s"] = [str(t) for t in integration]
        if aperture is not None:
            form["aperture_deg"] = str(aperture)
    if args.target:
        form["target"] = args.target
    from app.cli.jobs import submit
    from app.schemas import PassPublic

    body = submit(args, "/v1/passes", files={"files": ("frames.npz", data)}, data=form, timeout=300)
    answer = PassPublic.model_validate(body)
    if args.json:
        print(json.dumps(body, indent=1))
    else:
        print(f"pass {answer.id}:")
        _print_pass(answer, rec)
    if args.plot:
        _plot_pass(answer, rec, args.plot)
    return 0


def _truth_lvlh(rec: dict[str, Any], k: int) -> Any:
    from inference.rotations import rotation_matrix

    f = rec["frames"][k]
    return rotation_matrix(*f["attitude_lvlh"]["euler_zyx_deg"]) if "attitude_lvlh" in f else None


def _print_pass(result: PassResult, rec: dict[str, Any]) -> None:
    import numpy as np

    from inference.rotations import angle_deg, rotation_matrix

    z, y, x = result.attitude_lvlh.euler_zyx_deg
    bz, by, bx = result.uncertainty_deg
    print(
        f"fused, body to LVLH: z {z:.2f} y {y:.2f} x {x:.2f} deg (90 % bound {bz:.2f} / {by:.2f} / {bx:.2f}); "
        f"{result.used} frames used, {result.rejected} rejected"
        f"{'' if result.trusted else '; NOT TRUSTED'}"
    )
    print(result.stability)
    common = result.common_fit
    if common:
        print(
            f"fitted to {common.frames} frames' silhouettes at once (mean soft IoU {common.silhouette_iou:.3f}): "
            f"{common.moved_deg:.3f} deg from their robust mean"
        )
    fit = result.likelihood
    if result.refined_on == "image" and fit:
        print(
            f"refined on {fit['frames']:.0f} frames' images together under the set's map: {fit['moved_deg']:.3f} deg "
            f"from the silhouettes' answer (negative log-likelihood per pixel {fit['start_nll_per_pixel']:.4f} -> "
            f"{fit['nll_per_pixel']:.4f})"
        )
    alt = result.alternative_lvlh
    if alt:
        az, ay, ax = alt.euler_zyx_deg
        print(
            f"as many frames agree with z {az:.2f} y {ay:.2f} x {ax:.2f} deg (the near-mirror: the image plane "
            "barely turns over this pass); the frames' own answers chose the one above"
        )
    errors = []
    for f in result.frames:
        truth = _truth_lvlh(rec, f.index) if f.index < len(rec.get("frames", [])) else None
        err = ""
        if truth is not None:
            errors.append(angle_deg(rotation_matrix(*f.attitude_lvlh.euler_zyx_deg), truth))
            err = f", {errors[-1]:.2f} deg from the truth"
        why = f.rejected_because or ""
        state = "used" if f.used else f"rejected: {why if len(why) <= 90 else why[:87] + '...'}"
        at = f.observed_at.isoformat()
        sweep = ""
        if f.sweep_deg_s is not None and f.sweep_model_deg_s is not None:
            sweep = f", sweep {f.sweep_deg_s:.3f} deg/s (answer's {f.sweep_model_deg_s:.3f})"
        print(f"  {at[11:19]} {f.branch:<12} residual {f.residual_deg:.2f} deg{err}{sweep}; {state}")
    truth = _truth_lvlh(rec, 0) if rec.get("frames") else None
    if errors and truth is not None and result.stable:
        off = angle_deg(rotation_matrix(z, y, x), truth)
        print(
            f"against the simulated truth: fused {off:.3f} deg, single frames' median {float(np.median(errors)):.3f} deg"
        )


def _verdict(stable: bool | None) -> str:
    return "stable" if stable else "undecided (too few trusted frames)" if stable is None else "TURNING"


def _plot_pass(result: PassResult, rec: dict[str, Any], path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    times = [f.observed_at for f in result.frames]
    t0 = min(times)
    t = np.array([(x - t0).total_seconds() for x in times])
    each = np.array([f.attitude_lvlh.euler_zyx_deg for f in result.frames])
    bounds = np.array([[b if b is not None else np.nan for b in f.quality.uncertainty_deg] for f in result.frames])
    used = np.array([f.used for f in result.frames])
    fused = np.array(result.attitude_lvlh.euler_zyx_deg)
    ub = np.array(result.uncertainty_deg)
    alt = np.array(result.alternative_lvlh.euler_zyx_deg) if result.alternative_lvlh else None
    model = None
    if result.stable is False and result.attitude_at is not None:
        from inference.rotations import euler_from_matrix, rotation_matrix, so3_exp

        t_ref = (result.attitude_at - t0).total_seconds()
        dense = np.linspace(float(t.min()), float(t.max()), 200)
        w = np.radians(np.array(result.rate_deg_s, float))
        a_ref = rotation_matrix(*fused)
        model = np.array([euler_from_matrix(a_ref @ so3_exp((x - t_ref) * w)) for x in dense])
        model = fused + (model - fused + 180.0) % 360.0 - 180.0  # continuous through +-180
    fig, axes = plt.subplots(3, 1, figsize=(8, 7.5), sharex=True)
    for i, (ax, name) in enumerate(zip(axes, ("z (yaw)", "y (pitch)", "x (roll)"), strict=True)):
        ax.errorbar(t[used], each[used, i], yerr=bounds[used, i], fmt="o", ms=4, capsize=2, label="frame (90 % bound)")
        span = each[used, i] if used.any() else each[:, i]
        pad = max(1.0, 0.5 * float(np.ptp(span)), 3.0 * float(np.nanmax(bounds[used, i])) if used.any() else 1.0)
        lo, hi = float(span.min()) - pad, float(span.max()) + pad
        if (~used).any():  # rejected frames far off are drawn at the edge, so the used ones keep their scale
            ax.plot(t[~used], np.clip(each[~used, i], lo, hi), "x", color="tab:red", ms=7, label="rejected (clipped)")
        ax.set_ylim(lo, hi)
        if result.stable:
            ax.axhline(fused[i], color="tab:orange", label="fused")
            ax.axhspan(fused[i] - ub[i], fused[i] + ub[i], color="tab:orange", alpha=0.2)
        if result.stable and alt is not None:  # the other branch as many frames agree with; off scale: its value
            v = fused[i] + (alt[i] - fused[i] + 180.0) % 360.0 - 180.0
            if lo <= v <= hi:
                ax.axhline(v, color="tab:purple", ls=":", label="other branch (alternative_lvlh)")
            else:
                ax.text(0.01, 0.04, f"other branch: {alt[i]:.2f} deg (off scale)", transform=ax.transAxes, fontsize=8)
        elif model is not None:  # turning: the model's attitude over the pass, its bound at attitude_at
            ax.plot(dense, model[:, i], color="tab:orange", label="turning model")
            ax.errorbar([t_ref], [fused[i]], yerr=[ub[i]], fmt="D", color="tab:orange", capsize=3, ms=5)
        truth = [_truth_lvlh(rec, f.index) for f in result.frames if f.index < len(rec.get("frames", []))]
        if truth and truth[0] is not None and len(truth) == len(t):
            from inference.rotations import euler_from_matrix

            tv = np.array([euler_from_matrix(r) for r in truth])
            ax.plot(t, tv[:, i], "k--", lw=1, label="truth")
        ax.set_ylabel(f"{name}, deg")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8, ncol=4)
    axes[-1].set_xlabel(f"seconds after {t0:%Y-%m-%d %H:%M:%S} UTC")
    fig.suptitle(
        f"pass attitude, body to LVLH: {result.used} used, {result.rejected} rejected; {_verdict(result.stable)}",
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def cmd_passes(args: argparse.Namespace) -> int:
    """gsa passes list|show: your fused passes on the service."""
    from urllib.parse import quote

    from app.cli.common import print_listing, utc_text
    from app.schemas import PassPublic

    if args.passes_cmd == "show":
        body = call_server(
            args, "GET", f"/v1/passes/{quote(resolve_id(args, '/v1/passes', args.id, 'passes'), safe='')}"
        ).json()
        if args.json:
            print(json.dumps(body, indent=2))
        else:
            p = PassPublic.model_validate(body)
            print(f"pass {p.id} (plan {p.plan_id or '-'}, target {p.target}, {utc_text(p.created_at)})")
            _print_pass(p, {})
        return 0

    def row(p: dict[str, Any]) -> str:
        stable = "-" if p["stable"] is None else "stable" if p["stable"] else "turning"
        return (
            f"{p['id']:<36}  {utc_text(p['created_at']):<24}  {p['target'][:16]:<16} {p['frames']:>6} {p['used']:>5} "
            f"{('yes' if p['trusted'] else 'no'):<7} {stable:<8} {p.get('plan_id') or '-'}"
        )

    header = (
        f"{'id':<36}  {'created (UTC)':<24}  {'target':<16} {'frames':>6} {'used':>5} {'trusted':<7} {'motion':<8} plan"
    )
    return print_listing(args, "/v1/passes", {"plan_id": args.plan_id}, "{count} passes; newest {shown}:", header, row)
