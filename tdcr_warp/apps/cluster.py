"""The Ray backend of chunked sweeps: each chunk is a Ray task, so one sweep spans the cores,
GPUs and machines of a Ray cluster (``pip install -e ".[ray]"``).

A task receives the base scene (put in Ray's object store once), its chunk's sample rows,
the picklable job and the sweep's :class:`~tdcr_warp.io.store.ChunkStore`; it builds the batch,
solves it and writes its own chunk into the output folder (which the workers must see: one
machine, or a shared file system), returning only its count of failed rods; the driver
(:func:`tdcr_warp.apps.sweep.run_sweep`) checks what arrives.
Worker processes are reused from task to task, so a worker compiles or loads each Warp
module once, not once per chunk; workers that share a disk also share the kernel cache
(``WARP_CACHE_PATH`` of the driver, when set, is passed on to them). A task whose worker
dies is re-run by Ray (``max_retries``); a job's own error (bad sample row) is not retried.
"""

from __future__ import annotations

import os
import time

from tdcr_warp.apps.chunk import solve_chunk
from tdcr_warp.model.robot import InputError

__all__ = ["SweepError", "ray_chunks"]


class SweepError(RuntimeError):
    """A chunk could not be computed (its worker died more often than the retries allow)."""


def _import_ray():
    try:
        import ray
    except ImportError:
        raise InputError("--backend ray needs Ray: pip install -e \".[ray]\"") from None
    return ray


def _task(job, data: dict, store, c: int, rows: dict) -> tuple[int, dict]:
    """Run in a Ray worker: chunk c on one solver thread (the cluster schedules the cores),
    written by the worker; returns (failed rods, worker info)."""
    t0 = time.perf_counter()
    failed = store.write(c, solve_chunk(job, data, rows, threads=1), rows)
    return failed, {"pid": os.getpid(), "seconds": time.perf_counter() - t0}


def ray_chunks(data: dict, job, todo: list[int], store, samples, *, address: str | None = None,
               workers: int | None = None, gpus_per_task: float = 0.0, max_retries: int = 3,
               worker_info: list | None = None):
    """Yield ``(chunk index, failed rods)`` for the chunks in ``todo`` as Ray's tasks write
    them (``store``: the sweep's ChunkStore; ``samples(lo, hi)``: its sample rows).

    Joins the running Ray session, or the cluster at ``address``, or starts a local one of
    ``workers`` CPUs (default: all) that it shuts down at the end. One CPU (and
    ``gpus_per_task`` GPUs) per task; at most two tasks per CPU are in flight, so the object
    store holds a bounded number of chunks. ``worker_info`` collects each task's pid and
    seconds.
    """
    ray = _import_ray()
    if workers is not None and (not isinstance(workers, int) or workers < 1):
        raise InputError(f"--workers must be a positive integer, got {workers!r}")
    started = False
    if not ray.is_initialized():
        env = {"WARP_CACHE_PATH": os.environ["WARP_CACHE_PATH"]} if "WARP_CACHE_PATH" in os.environ else {}
        kw = {"address": address} if address else {"num_cpus": workers or os.cpu_count() or 1}
        try:
            ray.init(include_dashboard=False, log_to_driver=False, runtime_env={"env_vars": env}, **kw)
        except (ConnectionError, ValueError, RuntimeError) as e:
            raise InputError(f"--address {address!r}: cannot join the Ray cluster: {e}") from None
        started = True
    pending: dict = {}
    try:
        resources = ray.cluster_resources()
        cpus = int(resources.get("CPU", 1))
        if gpus_per_task and resources.get("GPU", 0) < gpus_per_task:
            raise InputError(f"--gpus-per-task {gpus_per_task}: the Ray cluster has {resources.get('GPU', 0)} GPUs")
        task = ray.remote(_task).options(num_cpus=1, num_gpus=gpus_per_task, max_retries=max_retries)
        data_ref = ray.put(data)
        queue = list(todo)
        while queue or pending:
            while queue and len(pending) < 2 * cpus:
                c = queue.pop(0)
                pending[task.remote(job, data_ref, store, c, samples(*store.bounds(c)))] = c
            ready, _ = ray.wait(list(pending), num_returns=1)
            for ref in ready:
                c = pending.pop(ref)
                try:
                    failed, info = ray.get(ref)
                except ray.exceptions.RayTaskError as e:
                    if isinstance(e.cause, InputError):
                        raise InputError(str(e.cause)) from None
                    raise SweepError(f"chunk {c} failed in its worker: {e.cause!r}") from None
                except ray.exceptions.RayError as e:
                    raise SweepError(f"chunk {c} was lost after {max_retries} retries ({type(e).__name__}); "
                                     "the chunks done so far are saved: rerun with --resume") from None
                if worker_info is not None:
                    worker_info.append({"chunk": c, **info})
                store.read(c, check_only=True)  # what the worker wrote, before it counts
                yield c, failed
    finally:
        # Tasks still in flight are not cancelled: ray.cancel racing with a finishing task aborts
        # the driver in Ray 2.60 ("Tried to complete task that was not pending"). Their results
        # are dropped with their references, and a driver that exits ends its job's tasks.
        if started:
            ray.shutdown()
