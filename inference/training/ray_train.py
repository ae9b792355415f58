"""``gsa train`` and ``gsa adapt`` on a Ray cluster (``GSA_RAY_ADDRESS``): Ray Train's TorchTrainer runs
:func:`train` (or :func:`adapt`) in N workers (training: a GPU each where the cluster has them; adaptation runs on
CPUs), which train one run with DistributedDataParallel as under torchrun.

Ray Train starts the workers' process group and sets RANK, WORLD_SIZE and LOCAL_RANK, so ``train`` finds itself
one of N processes and splits each step's batch with the others; worker 0 scores, checkpoints and writes the run.
The data set and the output folder must be where every worker reads and writes them: one machine, or storage
the cluster's nodes share. Progress comes from the run's own record (``training.json``, rewritten each epoch),
read here as it grows.
"""

from __future__ import annotations

import sys
import threading
import time
from pathlib import Path
from typing import Any

from inference.engine import EngineError, engine_for
from inference.files import read_json
from inference.training.options import TrainOptions


def _loop(config: dict[str, Any]) -> None:
    from inference.training.train import train

    train(config["data"], config["out"], config["options"])


def _adapt_loop(config: dict[str, Any]) -> None:
    from inference.training.adapt import adapt

    adapt(config["base"], config["frames"], config["out"], config["options"], config["target"])


def _follow(record: Path, stop: threading.Event, epochs: int) -> None:
    """Print each epoch the run records, as it records it."""
    seen = 0
    while not stop.wait(1.0):
        try:
            history = read_json(record, EngineError, "out").get("history", [])
        except (EngineError, ValueError, OSError):
            continue
        for h in history[seen:]:
            mae = h.get("test_mae_deg") or [float("nan")] * 3
            print(
                f"train: epoch {h['epoch']}/{epochs} done on the cluster: unet {h['unet_loss']:.4f} "
                f"swin {h['swin_loss']:.4f} test MAE z/y/x {mae[0]:.2f}/{mae[1]:.2f}/{mae[2]:.2f} deg",
                file=sys.stderr,
                flush=True,
            )
        seen = len(history)


def _fit(
    loop: Any, config: dict[str, Any], address: str, workers: int | None, out: Path, gpus_wanted: bool, cpus: float
) -> tuple[int, int, Any]:
    """Run ``loop`` in Ray Train workers; return (workers, cluster GPUs, the trainer's result)."""
    engine = engine_for(address, logs=True)  # connects (or says in one line why it cannot)
    try:
        import ray
        from ray.train import RunConfig, ScalingConfig
        from ray.train.torch import TorchTrainer
    except ImportError:
        raise EngineError("training on Ray needs Ray Train: pip install 'ray[train]==2.60.0'") from None
    gpus = int(ray.cluster_resources().get("GPU", 0)) if gpus_wanted else 0  # type: ignore[no-untyped-call]
    n = workers or (gpus if gpus else min(2, engine.workers))
    if n < 1 or n > max(engine.workers, gpus):
        raise EngineError(f"{n} training workers asked for; the cluster has {engine.workers} CPUs and {gpus} GPUs")
    trainer = TorchTrainer(
        loop,
        train_loop_config=config,
        scaling_config=ScalingConfig(num_workers=n, use_gpu=gpus > 0, resources_per_worker={"CPU": cpus}),
        run_config=RunConfig(storage_path=str(out.with_name(out.name + ".ray")), name="run"),
    )
    print(f"{n} Ray Train workers on {address} ({'a GPU each' if gpus else 'CPUs'})", file=sys.stderr, flush=True)
    try:
        result = trainer.fit()
    except Exception as exc:
        first = next((ln for ln in str(exc).splitlines() if ln.strip()), type(exc).__name__)
        raise EngineError(f"the run on {address} failed: {first[:400]}") from None
    if result.error is not None:
        raise EngineError(f"the run on {address} failed: {str(result.error).splitlines()[0][:400]}")
    return n, gpus, result


def adapt_on_ray(
    base: str | Path,
    frames: Any,
    out_dir: str | Path,
    options: Any,
    target: str | None,
    address: str,
    workers: int | None = None,
) -> dict[str, Any]:
    """Adapt on the cluster at ``address`` with ``workers`` Ray Train workers (default 2), DDP on their CPUs; the
    record is read back from the adapted set's card. Its lines reach this process's stderr as Ray forwards them."""
    out = Path(out_dir).resolve()
    frames_in = frames if not isinstance(frames, str | Path) else str(Path(frames).resolve())
    if isinstance(frames_in, list):
        frames_in = [str(Path(f).resolve()) for f in frames_in]
    config = {"base": str(Path(base).resolve()), "frames": frames_in, "out": str(out), "options": options}
    config["target"] = target
    t0 = time.perf_counter()
    n, _, _ = _fit(_adapt_loop, config, address, workers, out, False, 1.0)
    card: dict[str, Any] = read_json(out / "model_card.json", EngineError, "out")
    record: dict[str, Any] = card["adaptation"]
    record["ray"] = {"address": address, "workers": n, "seconds": round(time.perf_counter() - t0, 1)}
    return record


def train_on_ray(
    data_dir: str | Path, out_dir: str | Path, options: TrainOptions, address: str, workers: int | None = None
) -> dict[str, Any]:
    """Train on the cluster at ``address`` with ``workers`` Ray Train workers (default: its GPUs, else 2)."""
    out = Path(out_dir).resolve()
    out.mkdir(parents=True, exist_ok=True)
    config = {"data": str(Path(data_dir).resolve()), "out": str(out), "options": options}
    stop = threading.Event()
    follower = threading.Thread(target=_follow, args=(out / "training.json", stop, options.epochs), daemon=True)
    follower.start()
    t0 = time.perf_counter()
    try:
        n, gpus, _ = _fit(_loop, config, address, workers, out, True, float(options.threads or 1))
    finally:
        stop.set()
        follower.join(2.0)
    record: dict[str, Any] = read_json(out / "training.json", EngineError, "out")
    record["ray"] = {"address": address, "workers": n, "gpus": gpus, "seconds": round(time.perf_counter() - t0, 1)}
    return record
