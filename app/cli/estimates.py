"""gsa estimate and gsa estimates: one frame's attitude, locally or on the service."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from app.cli.common import (
    CliError,
    call_server,
    input_line,
    load_settings,
    local_models,
    print_listing,
    resolve_id,
    utc_text,
)

if TYPE_CHECKING:
    from app.schemas import EstimateResult


def cmd_estimates(args: argparse.Namespace) -> int:
    from urllib.parse import quote

    from app.schemas import EstimatePublic

    if args.estimates_cmd == "show":
        body = call_server(
            args, "GET", f"/v1/estimates/{quote(resolve_id(args, '/v1/estimates', args.id, 'estimates'), safe='')}"
        ).json()
        if args.json:
            print(json.dumps(body, indent=2))
        else:
            e = EstimatePublic.model_validate(body)
            _print_checked(e, prefix=f"estimate {e.id} ({e.input_name}, {utc_text(e.created_at)}): ")
        return 0

    def row(e: dict[str, Any]) -> str:
        z, y, x = e["attitude"]["euler_zyx_deg"]
        quality = e.get("quality")  # null on estimates made before the checks
        trusted = "-" if quality is None else "yes" if quality["trusted"] else "no"
        return (
            f"{e['id']:<36}  {utc_text(e['created_at']):<24}  {e['input_name'][:20]:<20} "
            f"{f'{z:.2f}, {y:.2f}, {x:.2f}':<22} {trusted:<7}  {e.get('plan_id') or '-'}"
        )

    header = f"{'id':<36}  {'created (UTC)':<24}  {'input':<20} {'z, y, x (deg)':<22} {'trusted':<7}  plan"
    return print_listing(
        args, "/v1/estimates", {"plan_id": args.plan_id}, "{count} estimates; newest {shown}:", header, row
    )


def _print_checked(body: EstimateResult, prefix: str = "") -> None:
    """Print an estimate's answer (the service's or a local one, one typed shape): attitude, quality, alternatives."""
    z, y, x = body.attitude.euler_zyx_deg
    q = body.attitude.quaternion_wxyz
    kind = "fitted" if body.refined else "network"
    print(
        f"{prefix}z {z:.2f} y {y:.2f} x {x:.2f} deg ({kind}, observation frame, target {body.target}); "
        f"quaternion w x y z {', '.join(f'{v:.5f}' for v in q)}"
    )
    net = body.attitude_network
    if net and body.refined:
        nz, ny, nx = net.euler_zyx_deg
        print(f"Swin alone: z {nz:.2f} y {ny:.2f} x {nx:.2f} deg")
    for label, att in (
        ("LVLH (the target's orbital frame)", body.attitude_lvlh),
        ("J2000", body.attitude_j2000),
    ):
        if att is not None:
            lz, ly, lx = att.euler_zyx_deg
            print(
                f"in {label}: z {lz:.2f} y {ly:.2f} x {lx:.2f} deg; quaternion w x y z "
                f"{', '.join(f'{v:.5f}' for v in att.quaternion_wxyz)}"
            )
    qual = body.quality
    if qual:
        bounds = " / ".join("-" if b is None else f"{b:.2f}" for b in qual.uncertainty_deg)
        state = "trusted" if qual.trusted else "NOT TRUSTED"
        print(f"{state}: silhouette IoU {qual.silhouette_iou:.3f}, 90 % bound z / y / x {bounds} deg")
        for r in qual.reasons:
            print(f"  - {r}")
    for alt in body.alternatives:
        az, ay, ax = alt.euler_zyx_deg
        what = "also fits" if alt.fitted else "the answer's near-mirror (unrefined)"
        print(
            f"{what}: z {az:.2f} y {ay:.2f} x {ax:.2f} deg ({alt.distance_deg:.0f} deg away, "
            f"IoU {alt.silhouette_iou:.3f}, fit {alt.fit_gap:+.4f})"
        )


def _one_frame(args: argparse.Namespace, data: bytes) -> tuple[str, bytes, bool]:
    """The one frame ``gsa estimate`` reads: the file itself, or frame ``--frame K`` of a stack (a ``gsa simulate``
    shard, whose frames are normalised and say so), as .npy bytes; with whether the file says it is normalised."""
    import io

    import numpy as np

    from app.errors import InputError
    from app.services import uploads as upload_svc

    name = Path(args.file).name
    if args.frame is None and not data.startswith(b"PK"):
        return name, data, False
    try:
        frames = upload_svc.decode(data, name, allow_stack=True)
    except InputError as exc:
        raise CliError(input_line(exc)) from None
    if args.frame is None:
        if len(frames) == 1:
            return name, data, frames[0].normalised
        raise CliError(f"{args.file} holds {len(frames)} frames: pick one with --frame K (0..{len(frames) - 1})")
    if not 0 <= args.frame < len(frames):
        raise CliError(f"--frame {args.frame}: {args.file} holds frames 0..{len(frames) - 1}")
    buf = io.BytesIO()
    np.save(buf, frames[args.frame].magnitude.astype(np.float32))
    return f"{name}[{args.frame}]", buf.getvalue(), frames[args.frame].normalised


def _normalised_hint(name: str, data: bytes, sent_normalised: bool, trusted: bool) -> None:
    """Say when an untrusted answer's frame may have been normalised twice: a real .npy frame whose values all lie
    in [0, 1], as the models' input does, sent without --normalised (one more normalisation squeezes it)."""
    import io

    import numpy as np

    if sent_normalised or trusted or not name.lower().endswith(".npy"):
        return
    try:
        arr = np.load(io.BytesIO(data), allow_pickle=False)
    except (ValueError, OSError):
        return
    if np.iscomplexobj(arr) or arr.size == 0 or not np.isfinite(arr).all():
        return
    if float(arr.min()) >= 0.0 and float(arr.max()) <= 1.0:
        print(
            "hint: every value of this frame lies in [0, 1], as the models' input does: if it already is that input "
            "(gsa simulate writes such frames), add --normalised, or it is normalised a second time"
        )


def cmd_estimate(args: argparse.Namespace) -> int:
    import numpy as np

    from app.errors import DOMAIN_ERRORS, input_error
    from app.schemas import EstimatePublic, EstimateResult

    if (args.plan_id or args.observed_at) and not args.server:
        raise CliError("--plan-id and --observed-at need --server: plans are stored by the service")
    if bool(args.plan_id) != bool(args.observed_at):
        raise CliError("give --plan-id and --observed-at together")
    if (args.range_cell_m is None) != (args.cross_range_cell_m is None):
        raise CliError("give --range-cell-m and --cross-range-cell-m together (the frame's cells in metres)")
    for name in ("range_cell_m", "cross_range_cell_m"):
        value = getattr(args, name)
        if value is not None and not 0 < value <= 100:
            raise CliError(f"--{name.replace('_', '-')} {value}: a cell size in metres, over 0 and at most 100")
    cells = None if args.range_cell_m is None else (args.range_cell_m, args.cross_range_cell_m)
    try:
        data = Path(args.file).read_bytes()
    except OSError as exc:
        raise CliError(f"cannot read {args.file}: {exc.strerror}") from None
    name, data, file_normalised = _one_frame(args, data)
    if args.server:
        form = {
            "resample": str(args.resample).lower(),
            "normalised": str(args.normalised or file_normalised).lower(),
            "refine": str(not args.no_refine).lower(),
        }
        if args.target:
            form["target"] = args.target
        if args.plan_id:
            form["plan_id"] = args.plan_id
        if args.observed_at:
            form["observed_at"] = args.observed_at
        if cells:
            form.update({"range_cell_m": str(cells[0]), "cross_range_cell_m": str(cells[1])})
        r = call_server(args, "POST", "/v1/estimates", files={"file": (name, data)}, data=form, timeout=60)
        answer = EstimatePublic.model_validate(r.json())
        _print_checked(answer, prefix=f"estimate {answer.id}: ")
        trusted = bool(answer.quality and answer.quality.trusted)
        _normalised_hint(name, data, bool(args.normalised or file_normalised), trusted)
        return 0
    from app.services import uploads as upload_svc

    settings = load_settings()
    try:
        est, checker = local_models(args, settings)
        (up,) = upload_svc.decode(data, name, allow_stack=False)
        model_cells = (checker.radar.range_cell_m, checker.radar.cross_range_cell_m)
        frame = upload_svc.prepare(
            up, est.img_size, args.resample, args.normalised or file_normalised, cells, model_cells
        )
        res = est.estimate(frame[None])
        t0 = time.perf_counter()
        checked = checker.check(
            frame,
            res.enhanced[0],
            res.angles_deg[0] if checker.networks else None,
            not args.no_refine,
            search_enhancer=est.search_enhancer,
        )
        t_fit = time.perf_counter() - t0
    except DOMAIN_ERRORS as exc:
        raise CliError(input_error(exc)[1]) from None
    body = EstimateResult.from_checked(
        checked,
        target=checker.model.name,
        model=est.identity,
        timings_s={**res.timings_s, "fit": t_fit},
        input_normalised=bool(args.normalised or file_normalised),
        cells_m=cells,
    )
    _print_checked(body)
    _normalised_hint(name, data, bool(args.normalised or file_normalised), bool(body.quality and body.quality.trusted))
    print(
        f"UNet++ {res.timings_s['unetpp'] * 1000:.0f} ms, Swin {res.timings_s['swin'] * 1000:.0f} ms, "
        f"fit and checks {t_fit * 1000:.0f} ms"
    )
    if args.plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        outline = checker.renderer.occupancy(np.asarray(checked.angles_deg, float)[None])[0] > 0.5
        z, y, x = (float(a) for a in checked.angles_deg)
        fig, ax = plt.subplots(1, 2, figsize=(9, 4.6))
        ax[0].imshow(frame, cmap="gray", vmin=0, vmax=1)
        ax[0].set_title("input (normalised) and the fitted projection")
        ax[1].imshow(np.clip(res.enhanced[0], 0, 1), cmap="gray", vmin=0, vmax=1)
        q = checked.quality
        ax[1].set_title(
            f"enhanced; fitted z {z:.1f} y {y:.1f} x {x:.1f} deg\n"
            f"IoU {q.silhouette_iou:.3f}, {'trusted' if q.trusted else 'NOT trusted'}",
            fontsize=10,
        )
        for a in ax:
            a.contour(outline, levels=[0.5], colors=["#ff7f0e"], linewidths=0.9)
            a.set_xlabel("cross-range cell (column)")
            a.set_ylabel("range cell (row)")
        fig.tight_layout()
        fig.savefig(args.plot, dpi=100)
        plt.close(fig)
        print(f"plot written to {args.plot}", file=sys.stderr)
    return 0
