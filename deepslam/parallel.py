"""Running independent pieces of an evaluation in parallel: local worker processes or a Ray cluster.

``parallel_map(fn, items)`` returns ``[fn(item) for item in items]`` in order, whichever way it runs, so a
sweep's results are the same bytes serially, in ``jobs`` worker processes or on Ray (on CPUs: every piece
is seeded by its own item, and each worker runs one torch thread). A piece that fails names itself.
"""

from __future__ import annotations

import os
import socket
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from typing import Callable, Sequence, TypeVar

from deepslam.errors import DeepslamError, InputError
from deepslam.progress import progress_bar

Item = TypeVar("Item")
Result = TypeVar("Result")


@dataclass(frozen=True)
class Workers:
    """Where the pieces run: ``jobs`` local processes (1: in this process), or the Ray cluster at
    ``ray_address`` (host:port). No local Ray cluster is started: Ray (2.60) listens on every network
    interface whatever node address it is given, so a cluster is something to start on purpose."""

    jobs: int = field(
        default=1, metadata={"help": "local worker processes (one torch thread each)", "min": 1, "max": 256}
    )
    ray_address: str | None = None  # the CLI's --ray ADDRESS

    def __post_init__(self):
        if self.jobs < 1:
            raise InputError(f"--jobs must be at least 1, got {self.jobs}")


class PieceFailed(DeepslamError, RuntimeError):
    """A piece of a parallel evaluation raised; the message names the piece."""


def _init_worker() -> None:
    import cv2
    import torch

    torch.set_num_threads(1)
    cv2.setNumThreads(1)


def parallel_map(
    fn: Callable[[Item], Result],
    items: Sequence[Item],
    workers: Workers = Workers(),
    describe: Callable[[Item], str] = str,
    progress: str | None = None,
) -> list[Result]:
    """``[fn(item) for item in items]``, run as ``workers`` says; progress counts finished pieces.
    ``fn`` must be a module-level function and items picklable when ``workers`` is not one local job."""
    if workers.ray_address is not None:
        return _on_ray(fn, items, workers, describe, progress)
    if workers.jobs == 1 or len(items) <= 1:
        results = []
        for item in progress_bar(items, desc=progress, unit="piece", disable=progress is None):
            results.append(_run(fn, item, describe))
        return results
    results: list = [None] * len(items)
    pool = ProcessPoolExecutor(max_workers=workers.jobs, initializer=_init_worker)
    try:
        futures = {pool.submit(fn, item): index for index, item in enumerate(items)}
        bar = progress_bar(total=len(items), desc=progress, unit="piece", disable=progress is None)
        for future in as_completed(futures):
            index = futures[future]
            try:
                results[index] = future.result()
            except Exception as error:  # noqa: BLE001 - re-raised with the piece named
                raise PieceFailed(f"{describe(items[index])} failed: {type(error).__name__}: {error}") from error
            bar.update(1)
        bar.close()
    except BaseException:  # a failed piece, Ctrl-C or SIGTERM: the workers stop now, not after their pieces
        _stop(pool)
        raise
    pool.shutdown()
    return results


def _stop(pool: ProcessPoolExecutor, timeout_s: float = 1.0) -> None:
    """Cancel what has not started and end the worker processes now: their pieces write no files, and a
    worker that caught the signal inside a piece would only go on to wait for the next one."""
    processes = list(getattr(pool, "_processes", {}).values())  # the executor offers no public handle on them
    pool.shutdown(wait=False, cancel_futures=True)
    for process in processes:
        process.kill()
    for process in processes:
        process.join(timeout_s)


def _run(fn, item, describe):
    try:
        return fn(item)
    except Exception as error:  # noqa: BLE001 - re-raised with the piece named
        raise PieceFailed(f"{describe(item)} failed: {type(error).__name__}: {error}") from error


def _on_ray(fn, items, workers: Workers, describe, progress) -> list:
    """The same on the Ray cluster at ``workers.ray_address`` (usage statistics off)."""
    try:
        import ray
    except ImportError:
        raise InputError('--ray needs Ray: pip install -e ".[ray]" (or pip install ray)') from None
    _check_reachable(workers.ray_address)
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    try:
        ray.init(address=workers.ray_address, log_to_driver=False)
    except (ConnectionError, RuntimeError, ValueError) as error:
        raise InputError(f"cannot reach a Ray cluster at {workers.ray_address}: {error}") from None
    try:
        remote = ray.remote(num_cpus=1)(_ray_piece)
        refs = [remote.remote(fn, item) for item in items]
        results: list = [None] * len(items)
        index_of = {ref: index for index, ref in enumerate(refs)}
        pending = list(refs)
        bar = progress_bar(total=len(items), desc=progress, unit="piece", disable=progress is None)
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            index = index_of[done[0]]
            try:
                results[index] = ray.get(done[0])
            except Exception as error:  # noqa: BLE001 - re-raised with the piece named
                raise PieceFailed(f"{describe(items[index])} failed: {error}") from error
            bar.update(1)
        bar.close()
        return results
    finally:
        ray.shutdown()


def _check_reachable(address: str, timeout_s: float = 3.0) -> None:
    """ValueError unless something listens at ``address`` (host:port, as `ray start --head` prints it)."""
    host, _, port = address.rpartition(":")
    try:
        with socket.create_connection((host or "127.0.0.1", int(port)), timeout=timeout_s):
            return
    except (OSError, ValueError):
        raise InputError(
            f"cannot reach a Ray cluster at {address} (give host:port as `ray start --head` printed it)"
        ) from None


def _ray_piece(fn, item):
    _init_worker()
    return fn(item)
