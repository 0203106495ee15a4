"""``simtest bench backend``: wall time of ``generate`` on the local and the Ray back end, and Ray's start-up.

The same dataset (config and seed) is generated four times into fresh folders: local with 1 and 2 workers, and
Ray (a local instance started by the run) with 1 and 2 CPUs. Each run's wall time includes starting its workers
(spawned processes or Ray), loading the objects in each worker and writing every file; the Ray rows also report
the start-up of the Ray instance alone (:attr:`simtest.backend.RunStats.startup_s`). The CPU seconds per frame
of the 1-worker local run are the basis of a cluster estimate (:meth:`BackendBench.estimate`).
"""

from __future__ import annotations

import os
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

from simtest.benchmarks.generate import cpu_seconds

__all__ = ["BackendBench", "BackendRow", "bench_backend"]


@dataclass(frozen=True)
class BackendRow:
    """One measured run: back end, workers, wall seconds, Ray start-up seconds (0 for local)."""

    backend: str
    workers: int
    seconds: float
    startup_s: float
    frames: int


@dataclass
class BackendBench:
    """The runs of :func:`bench_backend` and the CPU seconds per frame of the 1-worker local run."""

    width: int
    height: int
    scenes: int
    frames_per_scene: int
    cpu_s_per_frame: float
    cores: int
    bytes_per_frame: float = 0.0  # files written per frame (rgb, depth, masks, JSON), bytes
    rows: list[BackendRow] = field(default_factory=list)

    def table(self) -> str:
        """Markdown: one row per run (wall s, frames/s, Ray start-up s, ratio to local 1 worker)."""
        base = self.rows[0].seconds if self.rows else 0.0
        lines = [f"`simtest generate`, {self.scenes} scenes x {self.frames_per_scene} frames at "
                 f"{self.width}x{self.height}, {self.cores} cores", "",
                 "| back end | workers | wall s | frames/s | Ray start-up s | vs local 1 worker |",
                 "|---|---:|---:|---:|---:|---:|"]
        for r in self.rows:
            start = f"{r.startup_s:.1f}" if r.backend == "ray" else "-"
            lines.append(f"| {r.backend} | {r.workers} | {r.seconds:.1f} | {r.frames / r.seconds:.2f} | {start} | "
                         f"{base / r.seconds:.2f}x |")
        lines += ["", f"CPU time per frame (local, 1 worker, this process and its threads): "
                      f"{self.cpu_s_per_frame:.3f} s; written per frame: {self.bytes_per_frame / 1e3:.0f} kB"]
        return "\n".join(lines) + "\n"

    def estimate(self, frames: int = 1_000_000, nodes: int = 100, cores_per_node: int = 32,
                 efficiency: float = 0.8) -> str:
        """Paper estimate of ``frames`` frames on ``nodes`` nodes of ``cores_per_node`` cores, one scene per core
        at the measured CPU seconds per frame, ``efficiency`` of ideal scaling (start-up, stragglers, I/O)."""
        cpu_hours = frames * self.cpu_s_per_frame / 3600.0
        wall_min = 60.0 * cpu_hours / (nodes * cores_per_node * efficiency)
        return (f"{frames:,} frames x {self.cpu_s_per_frame:.3f} CPU s/frame = {cpu_hours:,.1f} CPU hours; on "
                f"{nodes} nodes x {cores_per_node} cores at {efficiency:.0%} efficiency: {wall_min:.1f} min of "
                f"rendering, writing {frames * self.bytes_per_frame / 1e9:,.0f} GB to the shared file system")


def bench_backend(width: int = 640, height: int = 480, scenes: int = 24, frames_per_scene: int = 25,
                  objects: str = "builtin", runs: tuple[tuple[str, int], ...] = (
                      ("local", 1), ("local", 2), ("ray", 1), ("ray", 2))) -> BackendBench:
    """Generate the same dataset with each ``(backend, workers)`` of ``runs`` and time it (seconds).

    The first run should be ``("local", 1)``: its CPU seconds per frame (this process, in-process rendering)
    are the per-frame cost reported.
    """
    from simtest.generators.config import GenerateConfig
    from simtest.generators.pipeline import generate

    cfg = GenerateConfig().replace(**{"objects": objects, "scenes": scenes, "frames_per_scene": frames_per_scene,
                                      "camera.width": width, "camera.height": height})
    bench = BackendBench(width, height, scenes, frames_per_scene, 0.0, os.cpu_count() or 1)
    with tempfile.TemporaryDirectory(prefix="simtest-bench-backend-") as tmp:
        for i, (backend, workers) in enumerate(runs):
            cpu0, t0 = cpu_seconds(children=True), time.perf_counter()
            rep = generate(cfg.replace(backend=backend, workers=workers), Path(tmp) / f"run{i}", progress=False)
            seconds = time.perf_counter() - t0
            if i == 0:
                bench.cpu_s_per_frame = (cpu_seconds(children=True) - cpu0) / max(1, rep.frames_written)
                written = sum(f.stat().st_size for f in (Path(tmp) / "run0").rglob("*") if f.is_file())
                bench.bytes_per_frame = written / max(1, rep.frames_written)
            bench.rows.append(BackendRow(backend, workers, seconds, rep.run.startup_s, rep.frames_written))
    return bench
