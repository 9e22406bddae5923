"""Where long jobs run (suite generation, sweeps): local worker processes (the
default) or a Ray cluster.

Both map a function over items and yield (item, result) as results arrive, at
most two jobs per worker in flight; the caller (the process that owns the
results database) writes what comes back. Jobs compute the same bytes wherever
they run, so both backends give identical rows.
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import os
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from typing import Any

from depotbench.core.errors import EnvironmentProblem, InputError
from depotbench.core.logs import DETAIL, follow_in_worker
from depotbench.core.main_guard import require_main_guard
from depotbench.core.numerics import apply_reference_environment
from depotbench.core.processes import children_block_sigint, exit_with_parent, release_sigint

LOG = logging.getLogger(__name__)
BACKENDS = ("local", "ray")
USER_ERRORS = (InputError, EnvironmentProblem)
"""What a job raises for the user to fix (the command line says it in one line)."""
KILL_WAIT_S = 5.0
"""How long a killed worker may take to be gone (it dies at once; this bounds a stuck kernel)."""


def single_threaded() -> None:
    """One thread per worker process: the workers are the parallelism (Mesa's llvmpipe,
    OpenMP, OpenBLAS and OpenCV would each start a thread per core).

    A spawned worker has imported numpy (through the parent's main module) before this
    runs, so OpenBLAS has read its environment already: its pool is limited at run time.
    Two workers with a BLAS thread per core each ran the sweep benchmark 2x slower.
    ``LP_NUM_THREADS=0`` makes llvmpipe rasterise in the calling thread; with 1 it hands
    every pass to a rasteriser thread of its own, which cost two generation workers about
    15 % more CPU per frame (80 against 68 ms)."""
    os.environ["OMP_NUM_THREADS"] = "1"
    os.environ["LP_NUM_THREADS"] = "0"
    import cv2
    from threadpoolctl import threadpool_limits

    cv2.setNumThreads(1)
    threadpool_limits(1)


def _init_local_worker(parent_pid: int, log_level: int = logging.WARNING) -> None:
    release_sigint()
    exit_with_parent(parent_pid)
    single_threaded()
    follow_in_worker(log_level)
    from depotbench.core.progress import use_thread_lock

    use_thread_lock()


def _top_up(queue: Iterator[tuple], running: dict, limit: int, submit: Callable[[tuple], Any]) -> bool:
    """Submit items from ``queue`` until ``limit`` run; False once it is empty. Items are taken
    as they are submitted, so one may be made when needed (a cluster's job puts its sequence
    into Ray's object store then, not all at the start)."""
    while len(running) < limit:
        item = next(queue, None)
        if item is None:
            return False
        running[submit(item)] = item
    return True


class LocalPool:
    """Spawned workers that ignore Ctrl-C, die with the parent and are killed on an error.
    With one worker and ``in_process``, jobs run in this process instead.

    The executor (its queues hold five named semaphores) is made at the first
    ``map_unordered``, inside the caller's ``try``/``close``, with Ctrl-C held until it is
    kept: made here, a Ctrl-C between it and the caller's ``try`` left it unclosed, and an
    interrupted command (which ends by ``os._exit``) drew three lines from the resource
    tracker about leaked semaphores (probe N27)."""

    ships = False
    """Workers share this machine's folders: jobs name their sequences by path."""

    def __init__(self, workers: int, in_process: bool = True) -> None:
        self.workers = workers
        self.parallel = workers > 1 or not in_process
        self.pool: ProcessPoolExecutor | None = None

    def _executor(self) -> ProcessPoolExecutor:
        if self.pool is None:
            require_main_guard("workers", self.workers)  # each spawned worker re-imports the script
            # Workers load numpy afresh: on the reference's code even where this process
            # loaded numpy before the bench (core/numerics.py), so their bytes are the locks'.
            apply_reference_environment()
            with children_block_sigint():  # a Ctrl-C now is raised once self.pool holds it
                self.pool = ProcessPoolExecutor(
                    self.workers,
                    mp_context=mp.get_context("spawn"),
                    initializer=_init_local_worker,
                    initargs=(os.getpid(), logging.getLogger("depotbench").getEffectiveLevel()),
                )
            LOG.log(DETAIL, "started a pool of %d spawned worker processes (one thread each)", self.workers)
        return self.pool

    def map_unordered(self, fn: Callable, items: Iterable[tuple]) -> Iterator[tuple[tuple, Any]]:
        if not self.parallel:
            LOG.log(DETAIL, "one worker: jobs run in this process")
            for item in items:
                yield item, fn(*item)
            return
        pool = self._executor()
        running: dict[Future, tuple] = {}
        queue, more = iter(items), True
        while more or running:
            with children_block_sigint():  # the first submit spawns the workers
                more = more and _top_up(queue, running, 2 * self.workers, lambda item: pool.submit(fn, *item))
            finished, _ = wait(running, return_when=FIRST_COMPLETED)
            for future in finished:
                yield running.pop(future), future.result()

    def close(self, failed: bool) -> None:
        if self.pool is None:
            return
        if failed:
            processes = list(getattr(self.pool, "_processes", {}).values())
            for process in processes:
                process.kill()
            for process in processes:  # dead before the caller cleans what they were writing
                process.join(KILL_WAIT_S)
            # Waiting lets the pool's queues be finalised: left to the interpreter's exit,
            # their semaphores were reported as leaked (two lines after the error's one).
            self.pool.shutdown(wait=True, cancel_futures=True)
        else:
            self.pool.shutdown(wait=True)


def _on_ray(fn: Callable, *args: Any) -> tuple[str, Any]:
    """A job on a Ray worker, with the node it ran on (the driver counts tasks per node)."""
    import ray

    single_threaded()
    return ray.get_runtime_context().get_node_id()[:8], fn(*args)


NODE_RETRIES = 3
"""How often Ray runs a task again when its node or worker process dies under it (a job's
own error is never retried: it is the job's outcome). A job computes the same bytes
wherever it runs and the driver writes each row once, so a retry changes no result."""
CLUSTER_LOCAL_VARIABLES = ("DEPOTBENCH_CACHE",)
"""Variables (and their ``_*`` family) naming this machine's folders: not sent to a cluster's
nodes, which keep their own caches where their own environment says."""


class RayPool:
    """Jobs as Ray tasks: a local Ray instance with ``workers`` CPUs, or the cluster at
    ``address``. On a cluster (``ships``) nothing is shared but Ray: jobs carry their
    sequences by content (``depotbench.scenes.shipping``), each node keeps its own caches,
    and results come back through Ray to this process, which alone writes the output. Every
    node runs the same depotbench (a different one fails its jobs with one line)."""

    def __init__(self, workers: int, address: str | None) -> None:
        try:
            import ray
        except ImportError:
            raise InputError("--backend ray: Ray is not installed: pip install 'depotbench[ray]'") from None
        self.ray = ray
        self.started = not ray.is_initialized()
        if self.started:
            # Ray's own INFO lines ("Connecting to existing Ray cluster") are no output of ours.
            options: dict[str, Any] = {
                "include_dashboard": False,
                "log_to_driver": False,
                "logging_level": logging.WARNING,
            }
            if address:
                options["address"] = address
            else:  # "local": a Ray of its own, never one that `ray start` left running here
                options |= {"address": "local", "num_cpus": workers, "object_store_memory": 200 * 1024 * 1024}
            env = {k: v for k, v in os.environ.items() if k.startswith("DEPOTBENCH_")}
            if address:
                env = {k: v for k, v in env.items() if not _names_a_folder_here(k)}
            ray.init(runtime_env={"env_vars": env} if env else None, **options)
        self.ships = address is not None
        """Whether jobs carry their sequences (a cluster: no folder of this machine is read there)."""
        self.workers = workers if not address else max(1, int(ray.cluster_resources().get("CPU", 1)))
        where = f"the cluster at {address}" if address else "a local Ray"
        LOG.log(DETAIL, "Ray: %s jobs at a time on %s", self.workers, where)
        self.remote = ray.remote(num_cpus=1, max_retries=NODE_RETRIES)(_on_ray)
        self.tasks_per_node: dict[str, int] = {}
        """Tasks finished per node (its Ray id's first 8 digits), logged when the pool closes."""

    def put(self, value: Any) -> Any:
        """``value`` in Ray's object store, for the nodes that need it."""
        return self.ray.put(value)

    def map_unordered(self, fn: Callable, items: Iterable[tuple]) -> Iterator[tuple[tuple, Any]]:
        running: dict[Any, tuple] = {}
        queue, more = iter(items), True
        while more or running:
            more = more and _top_up(
                queue, running, 2 * self.workers, lambda item: self.remote.remote(fn, *item)
            )
            if not running:
                break
            finished, _ = self.ray.wait(list(running), num_returns=1)
            for ref in finished:
                item = running.pop(ref)
                node, result = self._result(ref)
                self.tasks_per_node[node] = self.tasks_per_node.get(node, 0) + 1
                yield item, result

    def _result(self, ref: Any) -> Any:
        """A task's value, or the error it raised: a user's error (a bad file, a missing
        library) as itself, so that the command says it in one line, not inside Ray's
        ``RayTaskError`` with the worker's traceback (~30 lines); anything else, a bug of
        ours, keeps Ray's error and the worker's traceback."""
        try:
            return self.ray.get(ref)
        except self.ray.exceptions.RayTaskError as exc:
            if isinstance(exc.cause, USER_ERRORS):
                raise exc.cause from None
            raise

    def close(self, failed: bool) -> None:
        if self.ships and self.tasks_per_node:
            counts = ", ".join(f"{node} {n}" for node, n in sorted(self.tasks_per_node.items()))
            LOG.info(f"Ray: tasks per node: {counts}")
        if self.started:
            self.ray.shutdown()


def _names_a_folder_here(variable: str) -> bool:
    return any(variable == v or variable.startswith(v + "_") for v in CLUSTER_LOCAL_VARIABLES)


def make_pool(
    backend: str, workers: int, address: str | None = None, in_process: bool = True
) -> LocalPool | RayPool:
    if backend == "local":
        if address:
            raise InputError("--address applies to --backend ray only")
        return LocalPool(workers, in_process)
    if backend == "ray":
        return RayPool(workers, address)
    raise InputError(f"unknown backend {backend!r}; choose one of {', '.join(BACKENDS)}")
