"""The per-machine thread budget of worker processes: how many threads each worker's rasterizer (llvmpipe),
image writers and OpenCV get from its share of the cores, and how many workers share a machine (a joined Ray
cluster runs one unit per CPU on every node). :func:`worker_threads` is the one call of a command's workers."""

from __future__ import annotations

import os
from contextlib import AbstractContextManager
from dataclasses import dataclass

__all__ = ["ThreadBudget", "available_cores", "workers_per_machine", "thread_budget", "apply_thread_budget",
           "worker_threads", "blas_threads"]


@dataclass(frozen=True)
class ThreadBudget:
    """Threads of one rendering worker process, from its share of the cores.

    Attributes:
        cores: The worker's share of the cores (>= 1).
        llvmpipe: Mesa llvmpipe rasterizer threads (``LP_NUM_THREADS``); 0 rasterizes in the thread that renders.
        writers: Threads that encode images and write files beside the rendering thread.
        opencv: OpenCV's own worker threads (``cv2.setNumThreads``).
    """

    cores: int
    llvmpipe: int
    writers: int
    opencv: int


def available_cores() -> int:
    """Cores this process may run on (its CPU affinity where the OS reports it, else ``os.cpu_count()``)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def workers_per_machine(workers: int, ray_address: str | None = None) -> int:
    """Worker processes sharing one machine's cores: ``workers`` on this machine; on a joined Ray cluster
    (``ray_address`` set) every node runs one unit per CPU, so as many as it has cores."""
    return workers if ray_address is None else available_cores()


def thread_budget(workers: int, cores: int | None = None) -> ThreadBudget:
    """Threads for each of ``workers`` processes that render and write images on ``cores`` cores.

    Each worker gets ``cores // workers`` cores (at least 1). llvmpipe gets one rasterizer thread per core of
    the share, or none (rasterize in the rendering thread) when the share is one core: a separate rasterizer
    thread then only adds hand-offs, and the other workers keep the cores busy while this one renders. Image
    encoding (about a fifth of a frame's CPU time) needs at most two writer threads, one per core of the share.
    OpenCV gets the share for its own parallel loops.
    """
    total = available_cores() if cores is None else max(1, int(cores))
    share = max(1, total // max(1, int(workers)))
    return ThreadBudget(cores=share, llvmpipe=share if share > 1 else 0, writers=min(2, share), opencv=share)


def apply_thread_budget(workers: int, cores: int | None = None) -> ThreadBudget:
    """Apply :func:`thread_budget` to this process; call it in a worker process before its first render.

    Sets ``LP_NUM_THREADS`` (read when the GL context is made; a value already in the environment, e.g. the
    user's, is kept and reported in the returned budget) and OpenCV's thread count.
    """
    budget = thread_budget(workers, cores)
    lp = os.environ.setdefault("LP_NUM_THREADS", str(budget.llvmpipe))
    try:
        import cv2

        cv2.setNumThreads(budget.opencv)
    except ImportError:  # pragma: no cover - cv2 is a dependency; physics-only use does not need it
        pass
    try:
        llvmpipe = max(0, int(lp))
    except ValueError:
        llvmpipe = budget.llvmpipe
    return ThreadBudget(budget.cores, llvmpipe, budget.writers, budget.opencv)


def worker_threads(workers: int, ray_address: str | None = None, *, apply: bool = False) -> ThreadBudget:
    """The thread budget of one of a run's workers: ``workers`` local processes, or on a joined Ray cluster
    (``ray_address`` set) one per core of the node (:func:`workers_per_machine`).

    Args:
        apply: Also apply it to this process (:func:`apply_thread_budget`: ``LP_NUM_THREADS``, OpenCV threads);
            a worker does so once, before its first render.
    """
    machine = workers_per_machine(workers, ray_address)
    return apply_thread_budget(machine) if apply else thread_budget(machine)


def blas_threads(threads: int) -> AbstractContextManager:
    """A ``with`` block in which numpy's BLAS (OpenBLAS, MKL, ...) runs matrix products on at most ``threads``
    threads (>= 1), restored after (threadpoolctl).

    A process that shares the cores with other workers and runs small products between ONNX Runtime calls
    should hold its BLAS to its own share: OpenBLAS starts a pool of one thread per core whose threads wait
    for each other, so on busy cores a product waits for threads the scheduler has parked. Measured on two
    cores shared with two other runs: the template stage's feature matching (8 crops' 10240 features against
    about 400-600 templates) took 0.19 s a call, half of a real LM-O frame's time, where one thread takes
    about 2 ms; one frame, two runs side by side, 84 s with the default pool against 72 s, the same poses
    (docs/sim2real.md, eighteenth round).

    Raises:
        ValueError: ``threads`` is below 1.
    """
    from threadpoolctl import threadpool_limits

    if int(threads) < 1:
        raise ValueError(f"blas_threads: threads must be at least 1, got {threads!r}")
    return threadpool_limits(limits=int(threads), user_api="blas")
