"""Where shard work runs: this machine's processes, or a Ray cluster (``GSA_RAY_ADDRESS``).

Work that splits into independent pieces (a data set's shards, each hundreds of frames: a Ray task costs about a
millisecond, a frame 10-100) is a function over a list of arguments. :func:`engine_for` picks the engine from the
address: none, local processes (``ProcessPoolExecutor``); ``local``, a Ray instance started on this machine; else a
cluster's address (``HOST:PORT`` of a head started with ``ray start --head``, or ``ray://HOST:PORT`` for Ray
Client). An address that does not answer is a :class:`EngineError` within seconds, never a hang.

Results come back in the order of the arguments, so whatever writes them writes the same bytes whichever engine
computed them; each piece's seed is part of its arguments.
"""

from __future__ import annotations

import os
import socket
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from typing import Any, Protocol, TypeVar

from inference.errors import InferenceError

RAY_ENV = "GSA_RAY_ADDRESS"
CONNECT_TIMEOUT_S = 3.0
T = TypeVar("T")
R = TypeVar("R")


class EngineError(InferenceError):
    """A cluster that cannot be used: an address that does not answer, or Ray not installed."""

    def __init__(self, message: str, field: str | None = "ray_address") -> None:
        super().__init__(message, field=field)


class Engine(Protocol):
    name: str
    workers: int

    def map(self, fn: Callable[[T], R], items: Iterable[T]) -> Iterator[R]: ...


@dataclass
class LocalEngine:
    """This machine's processes (one: in this process, no pool)."""

    workers: int = 1
    name: str = "local"

    def map(self, fn: Callable[[T], R], items: Iterable[T]) -> Iterator[R]:
        items = list(items)
        if self.workers <= 1 or len(items) <= 1:
            yield from map(fn, items)
            return
        with ProcessPoolExecutor(min(self.workers, len(items))) as pool:
            yield from pool.map(fn, items)


@dataclass
class RayEngine:
    """Ray tasks, at most ``2 x workers`` in flight (the cluster's CPUs), results in the order asked."""

    address: str
    workers: int = 1
    name: str = "ray"

    def map(self, fn: Callable[[T], R], items: Iterable[T]) -> Iterator[R]:
        import ray

        remote = ray.remote(num_cpus=1, max_retries=2)(fn)
        pending = list(items)
        refs: list[Any] = []
        limit = max(2, 2 * self.workers)
        k = 0
        while k < len(pending) or refs:
            while k < len(pending) and len(refs) < limit:
                refs.append(remote.remote(pending[k]))
                k += 1
            yield ray.get(refs.pop(0))


def check_address(address: str, timeout: float = CONNECT_TIMEOUT_S) -> tuple[str, int]:
    """(host, port) of a cluster address that answers a TCP connection; else EngineError saying what to fix."""
    text = address.strip().removeprefix("ray://")
    host, sep, port_text = text.rpartition(":")
    if not sep or not host or not port_text.isdigit() or not 0 < int(port_text) < 65536:
        raise EngineError(
            f"{RAY_ENV}={address!r} is not an address: give HOST:PORT of a Ray head (ray start --head prints it), "
            "ray://HOST:PORT for Ray Client, or local"
        )
    try:
        with socket.create_connection((host, int(port_text)), timeout=timeout):
            pass
    except OSError as exc:
        raise EngineError(
            f"{RAY_ENV}={address}: no Ray head answers there ({exc.strerror or exc}); start one with "
            f"`ray start --head --port {port_text}` or unset {RAY_ENV} to run on this machine"
        ) from None
    return host, int(port_text)


def _ray_init(address: str, logs: bool = False) -> int:
    """Connect to (or start) Ray (``logs``: the workers' output forwarded here); return the cluster's CPU count."""
    try:
        import ray
    except ImportError:
        raise EngineError(f"{RAY_ENV} is set but Ray is not installed here: pip install 'ray==2.60.0'") from None
    if not ray.is_initialized():
        if address != "local":
            check_address(address)
        try:
            if address == "local":
                ray.init(include_dashboard=False, log_to_driver=logs, configure_logging=False)
            else:
                ray.init(address=address, log_to_driver=logs, configure_logging=False)
        except Exception as exc:  # refused: a token that does not match (RAY_AUTH_TOKEN), another Ray release...
            first = next((ln for ln in str(exc).splitlines() if ln.strip()), type(exc).__name__)
            raise EngineError(f"{RAY_ENV}={address}: Ray would not connect: {first[:300]}") from None
    resources: dict[str, float] = ray.cluster_resources()  # type: ignore[no-untyped-call]
    return max(1, int(resources.get("CPU", 1)))


def engine_for(address: str | None = None, workers: int | None = None, logs: bool = False) -> Engine:
    """The engine for ``address`` (default: ``GSA_RAY_ADDRESS``; unset or empty: this machine's processes);
    ``logs``: Ray forwards its workers' output here (the first connection of a process decides)."""
    address = (os.environ.get(RAY_ENV, "") if address is None else address).strip()
    if not address:
        return LocalEngine(max(1, workers or os.cpu_count() or 1))
    if address != "local":
        check_address(address)
    return RayEngine(address, _ray_init(address, logs))


def describe(engine: Engine) -> dict[str, Any]:
    """What ran the work, for a manifest or a job's record (not part of any content hash)."""
    out: dict[str, Any] = {"engine": engine.name, "workers": engine.workers}
    if isinstance(engine, RayEngine):
        out["address"] = engine.address
    return out
