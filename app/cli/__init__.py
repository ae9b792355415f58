"""The ``gsa`` command line: the parser, and each command imported from its module only when it runs.

``common`` (settings, the one-line errors, the client options) is all the parser needs;
``service`` (serve, db, keys), ``planning`` (plan, campaign, access, plans, campaigns, stations), ``estimates``
(estimate, estimates) and ``passes`` (simulate --pass, pass) hold the commands, and the
inference commands (simulate, train, ...) bring their own arguments from ``inference``.
Bad input prints one line on stderr and exits with status 2.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Callable
from typing import Any

from app.cli.common import EXAMPLE_PLANS, CliError, add_client_options


def _lazy(module: str, name: str) -> Callable[[argparse.Namespace], int]:
    """Return a command that imports ``app.cli.MODULE`` only when it runs, and calls its ``name``."""

    def command(args: argparse.Namespace) -> int:
        return int(getattr(importlib.import_module(f"app.cli.{module}"), name)(args))

    return command


def add_inference_command(sub: Any, name: str, module: str, help: str) -> argparse.ArgumentParser:
    """Register ``gsa NAME``, whose arguments and ``run`` live in ``inference.MODULE``.

    Its InferenceError (bad input) becomes the one-line error and exit 2 of every command.
    """
    mod = importlib.import_module(f"inference.{module}")
    p = sub.add_parser(name, help=help)
    mod.add_arguments(p)

    def command(args: argparse.Namespace) -> int:
        from inference.errors import InferenceError

        try:
            return int(mod.run(args))
        except InferenceError as exc:
            raise CliError(str(exc)) from None

    p.set_defaults(func=command)
    return p


# The inference commands: name, module of inference (its add_arguments and run), help.
INFERENCE_COMMANDS = (
    ("simulate", "simulation.dataset", "simulate a labelled ISAR data set (or --preview a few frames)"),
    ("train", "training.train", "train UNet++ and Swin on a simulated data set"),
    ("finetune", "training.finetune", "fine-tune Swin's last stage of a trained run on cached features (CPU)"),
    (
        "adapt",
        "training.adapt",
        "adapt a model set to a radar's labelled frames (fine-tune, export, recalibrate trust)",
    ),
    ("export", "export", "export a training run to ONNX with a model card"),
    ("calibrate", "trust", "fit the attitude checks' thresholds and 90-percent bounds on fresh frames (trust.json)"),
    ("compare", "evaluation.compare", "set training runs side by side: Swin's test error per epoch"),
    ("evaluate", "evaluation.evaluate", "the paper's Tables 4 and 7 for the ONNX models"),
)


def command_name(argv: list[str]) -> str | None:
    """Return the subcommand ``argv`` names (its first word that is not an option), if any."""
    return next((a for a in argv if not a.startswith("-")), None)


def build_parser(load: str | None = None) -> argparse.ArgumentParser:
    """Build gsa's parser; only the inference command ``load`` gets its real arguments (and imports its module)."""
    p = argparse.ArgumentParser(prog="gsa", description="GSA-ISAR: GSA scene planning and ISAR attitude estimation")
    sub = p.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("serve", help="migrate the database and start the API")
    s.add_argument("--host")
    s.add_argument("--port", type=int)
    s.add_argument("--workers", type=int, default=1)
    s.set_defaults(func=_lazy("service", "cmd_serve"))
    db = sub.add_parser("db", help="database maintenance")
    dbs = db.add_subparsers(dest="db_cmd", required=True)
    dbs.add_parser("upgrade", help="apply all migrations").set_defaults(func=_lazy("service", "cmd_db_upgrade"))
    k = sub.add_parser("keys", help="API keys")
    ks = k.add_subparsers(dest="keys_cmd", required=True)
    kc = ks.add_parser("create", help="create a key and print it once")
    kc.add_argument("name")
    kc.add_argument("--operator", help="operator the key belongs to (default: NAME)")
    kc.add_argument("--admin", action="store_true", help="the admin role: may also change the shared default models")
    ks.add_parser("list", help="list keys")
    kro = ks.add_parser("role", help="give a key a role: operator (its own objects) or admin (also shared models)")
    kro.add_argument("id")
    kro.add_argument("role", choices=["operator", "admin"])
    kr = ks.add_parser("revoke", help="revoke a key")
    kr.add_argument("id")
    k.set_defaults(func=_lazy("service", "cmd_keys"))
    pl = sub.add_parser("plan", help="plan a GSA scene from a JSON request (the body of POST /v1/plans)")
    pl.add_argument("file", nargs="?", help="the request (JSON); or --example")
    pl.add_argument("--example", choices=sorted(EXAMPLE_PLANS), help="plan a shipped example (examples/*.json)")
    add_client_options(pl, "plan on a running service (stored there; a station may be named)")
    pl.add_argument("--json", action="store_true", help="print JSON instead of a table")
    pl.add_argument("--plot", metavar="PNG", help="draw ground track, elevation and alignment error")
    pl.add_argument(
        "--export",
        metavar="DIR",
        help="also write the plan as opm.txt, oem.txt (CCSDS KVN), opm.xml, oem.xml (CCSDS XML), plan.czml, "
        "plan.geojson, access.csv and pointing.csv",
    )
    pl.set_defaults(func=_lazy("planning", "cmd_plan"))
    cp = sub.add_parser("campaign", help="plan a campaign of GSA scenes from a JSON request (POST /v1/campaigns)")
    cp.add_argument(
        "file",
        nargs="?",
        help="the request (JSON); or --example; or 'replan ID FILE': re-plan stored campaign ID from FILE, "
        '{"observer": <an orbit input>, "from": <UTC time>} (POST /v1/campaigns/ID/replan; needs --server)',
    )
    cp.add_argument("replan_args", nargs="*", metavar="ID FILE", help=argparse.SUPPRESS)
    cp.add_argument(
        "--example", choices=["paper"], help="the paper's target over 60 days (examples/paper-campaign.json)"
    )
    add_client_options(cp, "plan on a running service (stored there; a station may be named)")
    cp.add_argument("--json", action="store_true", help="print JSON instead of a table")
    cp.add_argument("--plot", metavar="PNG", help="draw the Delta-v spent over the span and each scene's line of sight")
    cp.add_argument(
        "--export", metavar="DIR", help="also write opm.txt, oem.txt (CCSDS KVN), campaign.czml and access.csv"
    )
    cp.set_defaults(func=_lazy("planning", "cmd_campaign"))
    for noun, func in (
        ("plans", _lazy("planning", "cmd_plans")),
        ("campaigns", _lazy("planning", "cmd_campaigns")),
        ("estimates", _lazy("estimates", "cmd_estimates")),
        ("passes", _lazy("passes", "cmd_passes")),
    ):
        c = sub.add_parser(noun, help=f"your {noun} stored on the service (list, show)")
        cs = c.add_subparsers(dest=f"{noun}_cmd", required=True)
        cl = cs.add_parser("list", help=f"your {noun}, newest first")
        cl.add_argument("--limit", type=int, default=20)
        cl.add_argument("--json", action="store_true")
        if noun in ("plans", "campaigns"):
            cl.add_argument("--target-name", help=f"only this target's {noun}")
        else:
            cl.add_argument("--plan-id", help=f"only the {noun} tied to this plan")
        cw = cs.add_parser("show", help=f"one of your {noun}")
        cw.add_argument("id")
        cw.add_argument("--json", action="store_true")
        for q in (cl, cw):
            add_client_options(q, "the service")
        c.set_defaults(func=func)
    jb = sub.add_parser(
        "jobs", help="your long work on the service: adaptations, data sets, campaigns (list, show, cancel, wait)"
    )
    jbs = jb.add_subparsers(dest="jobs_cmd", required=True)
    jbl = jbs.add_parser("list", help="your jobs, newest first")
    jbl.add_argument("--limit", type=int, default=20)
    jbl.add_argument(
        "--kind", choices=["adaptation", "dataset", "campaign", "reestimate", "pass"], help="only jobs of this kind"
    )
    jbl.add_argument("--state", choices=["queued", "running", "done", "failed", "cancelled"], help="only in this state")
    jbl.add_argument("--json", action="store_true")
    jbw = jbs.add_parser("show", help="one job: state, progress, result, log tail")
    jbw.add_argument("id")
    jbw.add_argument("--json", action="store_true")
    jbc = jbs.add_parser("cancel", help="cancel a queued or running job")
    jbc.add_argument("id")
    jbd = jbs.add_parser("delete", help="remove an ended job with its files (a data set goes with its job)")
    jbd.add_argument("id")
    jbt = jbs.add_parser(
        "wait", help="follow a job to its end with a progress bar (exit 0: done; 1: failed or cancelled)"
    )
    jbt.add_argument("id")
    jbt.add_argument("--timeout", type=float, default=0, help="give up after this many seconds (default: never)")
    jbt.add_argument("--every", type=float, default=1.0, help="seconds between looks (default 1)")
    jbt.add_argument("--json", action="store_true", help="print the finished job as JSON")
    for q in jbs.choices.values():
        add_client_options(q, "the service")
    jb.set_defaults(func=_lazy("jobs", "cmd_jobs"))
    lb = sub.add_parser("labelled", help="your labelled frames on the service (add a folder, list, delete)")
    lbs = lb.add_subparsers(dest="labelled_cmd", required=True)
    lba = lbs.add_parser("add", help="store a folder of labelled frames (one .npz each, inference.labelled's format)")
    lba.add_argument("folder")
    lba.add_argument("--target", required=True, help="the target model the frames show (e.g. tiangong-like)")
    lba.add_argument("--plan-id", help="the stored plan whose geometry places labels given in J2000")
    lba.add_argument("--scene", help="the scene of frames whose file names none")
    lba.add_argument("--batch", type=int, default=32, help="files per request (default 32)")
    lbl = lbs.add_parser("list", help="your labelled frames of a target, with counts per scene and coverage")
    lbl.add_argument("--target", required=True)
    lbl.add_argument("--scene", help="only this scene's frames")
    lbl.add_argument("--limit", type=int, default=20)
    lbd = lbs.add_parser("delete", help="delete your labelled frames of a target: one scene's, or --all")
    lbd.add_argument("--target", required=True)
    lbd.add_argument("--scene", help="delete this scene's frames")
    lbd.add_argument("--all", action="store_true", help="delete every labelled frame of yours of the target")
    for q in (lba, lbl, lbd):
        q.add_argument("--json", action="store_true")
        add_client_options(q, "the service")
    lb.set_defaults(func=_lazy("labelled", "cmd_labelled"))
    st = sub.add_parser("stations", help="your named stations on the service (list, show, add, delete)")
    sts = st.add_subparsers(dest="stations_cmd", required=True)
    stl = sts.add_parser("list", help="your stations by name")
    stl.add_argument("--limit", type=int, default=100)
    stl.add_argument("--json", action="store_true")
    sta = sts.add_parser("add", help="store a station from a JSON file (name, latitude_deg, longitude_deg, mask, ...)")
    sta.add_argument("file")
    for verb in ("show", "delete"):
        sts.add_parser(verb, help=f"{verb} one station").add_argument("name")
    for q in sts.choices.values():
        add_client_options(q, "the service")
    st.set_defaults(func=_lazy("planning", "cmd_stations"))
    ac = sub.add_parser(
        "access",
        help="access windows from a JSON request (the body of POST /v1/access-windows); a catalogue (targets) is "
        "written a window a line, as JSON lines or CSV (its format)",
    )
    ac.add_argument("file")
    ac.add_argument("--json", action="store_true")
    ac.add_argument(
        "--workers",
        type=int,
        default=1,
        help="a catalogue's shards on this many processes (default 1); with GSA_RAY_ADDRESS set, as Ray tasks there",
    )
    ac.set_defaults(func=_lazy("planning", "cmd_access"))
    for name, module, help in INFERENCE_COMMANDS:
        if name == load:
            p_inf = add_inference_command(sub, name, module, help)
            if name == "simulate":  # --pass needs the planner's geometry, so it lives here, not in inference
                from app.cli.passes import add_pass_arguments, pass_or_data_set

                add_pass_arguments(p_inf)
                p_inf.set_defaults(func=pass_or_data_set(p_inf.get_default("func")))
            if name == "adapt":  # --plan places J2000 labels by the planner's geometry: here too, not in inference
                from app.cli.labelled import adapt_with_plan, add_plan_argument

                add_plan_argument(p_inf)
                p_inf.set_defaults(func=adapt_with_plan(p_inf.get_default("func")))
        else:
            # Not asked for: a stand-in that keeps `gsa --help` from importing torch and the simulator.
            sub.add_parser(name, help=help, add_help=False)
    es = sub.add_parser("estimate", help="estimate the attitude in one ISAR frame (.npy, .npz, PNG, TIFF)")
    es.add_argument("file")
    es.add_argument("--models", help="model directory (default: GSA_MODEL_DIR or the shipped models)")
    es.add_argument("--resample", action="store_true", help="resample a frame of another size")
    es.add_argument(
        "--frame", type=int, help="frame K of a stack (.npz [N, H, W], e.g. a gsa simulate shard, read as it is)"
    )
    es.add_argument(
        "--normalised",
        action="store_true",
        help="the frame is already normalised (a frame of a gsa simulate data set): take it as sent",
    )
    add_client_options(es)
    es.add_argument("--plot", metavar="PNG", help="draw the input and the enhanced frame with the fitted outline")
    es.add_argument("--no-refine", action="store_true", help="answer Swin's estimate, without the fit")
    es.add_argument("--target", help="the target the frame shows (default GSA_DEFAULT_TARGET: tiangong-like)")
    es.add_argument("--plan-id", help="with --server: one of your plans, to place the attitude in LVLH and J2000")
    es.add_argument("--observed-at", help="with --server and --plan-id: when the frame was observed (ISO 8601 UTC)")
    es.add_argument("--range-cell-m", type=float, help="the frame's range cell (rows) in metres: resample in metres")
    es.add_argument("--cross-range-cell-m", type=float, help="the frame's cross-range cell (columns) in metres")
    es.set_defaults(func=_lazy("estimates", "cmd_estimate"))
    ps = sub.add_parser("pass", help="fuse a pass's frames into one attitude in the target's orbital frame (LVLH)")
    ps.add_argument("folder", help="a folder with frames.npz and pass.json, as gsa simulate --pass writes")
    ps.add_argument("--plan", metavar="PLAN.json", help="the plan request the pass belongs to (default: pass.json's)")
    ps.add_argument("--models", help="model directory (default: GSA_MODEL_DIR or the shipped models)")
    ps.add_argument("--target", help="the target the frames show (default GSA_DEFAULT_TARGET: tiangong-like)")
    ps.add_argument("--json", action="store_true", help="print the fused pass as JSON")
    ps.add_argument("--plot", metavar="PNG", help="draw each frame's LVLH attitude with its bound beside the fused one")
    add_client_options(ps, "send it to a running service (POST /v1/passes) instead")
    ps.add_argument("--plan-id", help="with --server: the stored plan the pass belongs to")
    ps.set_defaults(func=_lazy("passes", "cmd_pass"))
    return p


def _quiet_stdout() -> None:
    """Point stdout at the null device, so the interpreter's final flush of a closed pipe raises nothing."""
    import os

    try:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    except (OSError, ValueError):  # no real stdout (a test's capture): nothing to flush into a pipe
        pass


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    args = build_parser(command_name(argv)).parse_args(argv)
    try:
        return int(args.func(args))
    except CliError as exc:
        print(f"gsa: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:  # the reader went away (`gsa plans show ID | head`): stop quietly, as Unix tools do
        _quiet_stdout()
        return 0
    except Exception as exc:  # the service's settings (GSA_*) that cannot be used: one line, naming the setting
        from pydantic import ValidationError

        if not (isinstance(exc, ValidationError) and exc.title == "Settings"):
            raise
        err = exc.errors()[0]
        where = "GSA_" + "_".join(str(p) for p in err.get("loc", ())).upper() if err.get("loc") else "settings"
        print(f"gsa: error: {where}: {err['msg'].removeprefix('Value error, ')}", file=sys.stderr)
        return 2
