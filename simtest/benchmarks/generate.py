"""Speed benchmarks, reported as ratios against raw MuJoCo measured in the same run.

``bench_generate``: frames/s of the whole ``generate`` pipeline with one worker (its scene loop: sampling,
building, settling the next scene while the current one renders, rendering, annotation, image and JSON writing)
against raw ``mujoco.Renderer`` rendering of the same outputs (RGB, depth and segmentation: three ``render()``
calls per frame, MuJoCo's own API for them) for the same settled scenes and camera poses, each twice in the order
pipeline, raw, raw, pipeline so both see the same machine load; the CPU time per annotated frame
(the process and its worker processes, all threads), also by thread group where Linux reports it
(:class:`ThreadCpu`: rendering, llvmpipe's rasterizers, annotation, writers, the scene made ahead); and 1 vs 2
workers. With 2 workers, throughput is given
both as frames over the busy time of the slower worker and as frames over the wall time including worker
start-up (about 1.5 s of imports and object loading per process), each also as a fraction of the ideal
``cores / (CPU seconds per frame of one worker)``.

``bench_profiles``: seconds per frame of each render profile at each image size, 1 and 2 workers, and for
``pbr`` the samples per pixel and the Mitsuba variant (and libLLVM) its manifest recorded.
"""

from __future__ import annotations

import os
import resource
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

from simtest.generators.config import GenerateConfig
from simtest.render.pbr_stages import process_stages

__all__ = ["bench_generate", "GenerateBench", "bench_profiles", "ProfileBench", "ProfileRow", "cpu_seconds",
           "ThreadCpu"]


@dataclass
class GenerateBench:
    """One run of :func:`bench_generate` (frames/s, CPU milliseconds per frame)."""

    width: int
    height: int
    objects_per_scene: int
    scenes: int
    frames_per_scene: int
    pipeline_fps: float
    raw_fps: float
    pipeline_fps_2workers: float | None
    pipeline_fps_2workers_wall: float | None = None
    cpu_ms_per_frame: float = 0.0
    cpu_ms_per_frame_2workers: float | None = None
    cores: int = 1
    cpu_ms_per_frame_2workers_scenes: float | None = None
    #: CPU ms per annotated frame of one worker by thread group (:class:`ThreadCpu`), largest first; empty
    #: where the operating system does not report per-thread CPU time.
    cpu_ms_by_thread: dict[str, float] = field(default_factory=dict)

    @property
    def ratio(self) -> float:
        return self.pipeline_fps / self.raw_fps if self.raw_fps else 0.0

    @property
    def speedup_2workers(self) -> float | None:
        return None if self.pipeline_fps_2workers is None else self.pipeline_fps_2workers / self.pipeline_fps

    @property
    def ideal_fps(self) -> float:
        """``cores / (CPU seconds per frame of one worker)``: frames/s if every core did pipeline work."""
        return self.cores / (self.cpu_ms_per_frame / 1000.0) if self.cpu_ms_per_frame > 0 else 0.0

    def efficiency_2workers(self, wall: bool = False) -> float | None:
        """2-worker frames/s (busy time, or wall time with ``wall``) over :attr:`ideal_fps`."""
        fps = self.pipeline_fps_2workers_wall if wall else self.pipeline_fps_2workers
        return None if fps is None or not self.ideal_fps else fps / self.ideal_fps

    def to_dict(self) -> dict:
        """The measurement as JSON-ready data: ``{"kind": "generate", ...}`` (the fields, frames/s, CPU ms)."""
        from dataclasses import asdict

        return {"kind": "generate", **asdict(self), "ratio": self.ratio, "ideal_fps": self.ideal_fps}

    def table(self) -> str:
        rows = [
            "| measurement | value |", "|---|---|",
            f"| image size | {self.width}x{self.height} |",
            f"| objects per scene | {self.objects_per_scene} (+ distractors 0-2) |",
            f"| scenes x views per scene | {self.scenes} x {self.frames_per_scene} |",
            f"| raw MuJoCo render (rgb + depth + seg), frames/s | {self.raw_fps:.2f} |",
            f"| full pipeline, 1 worker, annotated frames/s | {self.pipeline_fps:.2f} |",
            f"| pipeline / raw | {self.ratio:.2f} |",
            f"| CPU ms per annotated frame, 1 worker (all threads) | {self.cpu_ms_per_frame:.1f} |",
            f"| cores; ideal frames/s = cores / CPU s per frame | {self.cores}; {self.ideal_fps:.2f} |",
        ]
        if self.cpu_ms_by_thread:
            parts = ", ".join(f"{name} {ms:.1f}" for name, ms in self.cpu_ms_by_thread.items())
            rows.append(f"| CPU ms per frame by thread, 1 worker (threads that ended between two reads: not "
                        f"attributed) | {parts} |")
        if self.pipeline_fps_2workers is not None:
            rows += [
                f"| full pipeline, 2 workers, frames/s (busy time of the slower worker) | "
                f"{self.pipeline_fps_2workers:.2f} |",
                f"| 2 workers / 1 worker | {self.speedup_2workers:.2f} |",
                f"| 2 workers (busy) / ideal | {self.efficiency_2workers():.2f} |",
                f"| 2 workers, frames/s including worker start-up | {self.pipeline_fps_2workers_wall:.2f} |",
                f"| 2 workers (with start-up) / ideal | {self.efficiency_2workers(wall=True):.2f} |",
                f"| 2 workers / raw: busy time; with start-up (the whole machine against rendering alone, which "
                f"also uses every core) | {self.pipeline_fps_2workers / self.raw_fps:.2f}; "
                f"{self.pipeline_fps_2workers_wall / self.raw_fps:.2f} |",
                f"| CPU ms per frame, 2 workers: scene work / with start-up and parent | "
                f"{self.cpu_ms_per_frame_2workers_scenes:.1f} / {self.cpu_ms_per_frame_2workers:.1f} |",
                f"| 2 workers (busy) / (cores / their scene-work CPU s per frame) | "
                f"{self.pipeline_fps_2workers * self.cpu_ms_per_frame_2workers_scenes / 1000.0 / self.cores:.2f} |",
            ]
        return "\n".join(rows)


def cpu_seconds(children: bool = False) -> float:
    """CPU seconds (user + system, all threads) of this process, plus its waited-for child processes."""
    who = [resource.RUSAGE_SELF] + ([resource.RUSAGE_CHILDREN] if children else [])
    return sum(r.ru_utime + r.ru_stime for r in map(resource.getrusage, who))


def thread_groups() -> tuple[tuple[str, str], ...]:
    """``(thread name prefix, group)`` pairs of :class:`ThreadCpu`: Python's thread names as the pipeline's
    thread owners give them, or the OS's for native threads (llvmpipe's rasterizers)."""
    from simtest.generators.pipeline import ScenesAhead
    from simtest.generators.views_behind import ViewsBehind
    from simtest.io.bop import SceneWriter

    return (("MainThread", "rendering"), (ViewsBehind.THREAD_NAME, "annotation"),
            (ScenesAhead.THREAD_NAME, "scene ahead"), (SceneWriter.THREAD_NAME, "writers"), ("llvmpipe", "llvmpipe"))


class ThreadCpu:
    """CPU seconds of this process's threads by group (:func:`thread_groups`, the rest as "other") while a
    ``with`` block runs, from Linux's per-thread counters (``/proc/self/task``: ``schedstat``, nanoseconds).

    Threads are read every ``interval`` seconds; a thread that ends between two reads loses what it ran since
    the last one (at most ``interval`` per thread), so the groups can add up to slightly less than the
    process's CPU time. :attr:`available` is ``False`` (and :meth:`groups` empty) where there is no such file.
    """

    def __init__(self, interval: float = 0.02) -> None:
        import threading

        self.interval = interval
        self.available = os.path.exists(f"/proc/self/task/{threading.get_native_id()}/schedstat")
        self._start: dict[int, float] = {}
        self._last: dict[int, tuple[str, float]] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="simtest-thread-cpu", daemon=True)
        self._groups = thread_groups()

    def _group(self, name: str) -> str:
        for prefix, group in self._groups:
            if name.startswith(prefix):
                return group
        return "other"

    def _read(self) -> dict[int, tuple[str, float]]:
        import threading

        names = {t.native_id: t.name for t in threading.enumerate()}
        out = {}
        for tid in os.listdir("/proc/self/task"):
            try:
                with open(f"/proc/self/task/{tid}/schedstat") as fh:
                    ns = int(fh.read().split()[0])
                with open(f"/proc/self/task/{tid}/comm") as fh:
                    comm = fh.read().strip()
            except (FileNotFoundError, ProcessLookupError, ValueError, IndexError):
                continue  # the thread ended while being read
            out[int(tid)] = (names.get(int(tid), comm), ns * 1e-9)
        return out

    def _run(self) -> None:
        while not self._stop.wait(self.interval):
            self._last.update(self._read())

    def __enter__(self) -> "ThreadCpu":
        if self.available:
            self._start = {tid: cpu for tid, (_, cpu) in self._read().items()}
            self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        if self.available:
            self._stop.set()
            self._thread.join()
            self._last.update(self._read())

    def groups(self) -> dict[str, float]:
        """CPU seconds by group while the block ran (this sampler's own thread left out), largest first."""
        out: dict[str, float] = {}
        for tid, (name, cpu) in self._last.items():
            if name == "simtest-thread-cpu":
                continue
            group = self._group(name)
            out[group] = out.get(group, 0.0) + cpu - self._start.get(tid, 0.0)
        return dict(sorted(out.items(), key=lambda kv: -kv[1]))


def _raw_seconds(cfg: GenerateConfig, objects, scene_id: int) -> tuple[float, int]:
    """Seconds of raw ``mujoco.Renderer`` rendering (rgb, depth, seg) of every view of scene ``scene_id``
    (sampling, building and settling excluded), and the number of views."""
    import mujoco

    from simtest.generators.builder import DRAWN_GROUPS
    from simtest.generators.pipeline import prepare_scene
    from simtest.generators.recorder import scene_cameras

    scene, _, _, _ = prepare_scene(cfg, objects, scene_id)
    cams = scene_cameras(cfg, scene)
    opt = mujoco.MjvOption()
    opt.geomgroup[:] = 0
    for g in DRAWN_GROUPS:
        opt.geomgroup[g] = 1
    r = mujoco.Renderer(scene.model, cfg.camera.height, cfg.camera.width)
    r.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = False
    r.scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = False
    r.scene.flags[mujoco.mjtRndFlag.mjRND_SKYBOX] = False
    total = 0.0
    for cam, _ in cams:
        scene.set_camera(cam)
        t0 = time.perf_counter()
        r.update_scene(scene.data, camera=scene.camera_id, scene_option=opt)
        r.render()
        r.enable_depth_rendering()
        r.render()
        r.disable_depth_rendering()
        r.enable_segmentation_rendering()
        r.render()
        r.disable_segmentation_rendering()
        total += time.perf_counter() - t0
    r.close()
    return total, len(cams)


def _pipeline_run(cfg: GenerateConfig, objects, split_dir: Path) -> tuple[float, float, int, dict[str, float]]:
    """One worker making every scene of ``cfg`` as ``simtest generate`` does (its scene loop, with the next
    scene built and settled ahead while the current one renders), without the once-per-run files (manifest,
    models).

    Returns:
        ``(seconds, CPU seconds of every thread, frames, CPU seconds by thread group)`` (:class:`ThreadCpu`).
    """
    from simtest.generators.pipeline import GenerateReport, run_scenes

    split_dir.mkdir(parents=True)
    report = GenerateReport(split_dir.parent, cfg.scenes, 0, 0, 0, 0.0)
    with ThreadCpu() as threads:
        cpu0, t0 = cpu_seconds(children=True), time.perf_counter()
        run_scenes(cfg, objects, list(range(cfg.scenes)), split_dir, report, None)
        seconds, cpu = time.perf_counter() - t0, cpu_seconds(children=True) - cpu0
    return seconds, cpu, report.frames_written, threads.groups()


def _one_worker(cfg: GenerateConfig, objects, tmp: Path, rounds: int = 2
                ) -> tuple[float, float, float, int, dict[str, float]]:
    """The pipeline with one worker and raw rendering of the same scenes, ``rounds`` times each, in the order
    pipeline, raw, raw, pipeline, ... (a load that drifts during the benchmark weighs on both alike).

    Returns:
        ``(pipeline seconds, raw seconds, pipeline CPU seconds, frames, pipeline CPU seconds by thread group)``
        per round (means).
    """
    pipe = raw = cpu = 0.0
    frames = 0
    by_thread: dict[str, float] = {}
    order = [k % 2 == 0 for k in range(rounds)]  # pipeline first in even rounds
    for k, pipeline_first in enumerate(order):
        for step in ((True, False) if pipeline_first else (False, True)):
            if step:
                s, c, n, groups = _pipeline_run(cfg, objects, tmp / f"w1_{k}" / cfg.split)
                pipe, cpu, frames = pipe + s, cpu + c, n
                for name, seconds in groups.items():
                    by_thread[name] = by_thread.get(name, 0.0) + seconds / rounds
            else:
                raw += sum(_raw_seconds(cfg, objects, scene_id)[0] for scene_id in range(cfg.scenes))
    return pipe / rounds, raw / rounds, cpu / rounds, frames, by_thread


def bench_generate(width: int = 640, height: int = 480, objects_per_scene: int = 10, scenes: int = 8,
                   frames_per_scene: int = 10, objects: str = "builtin", two_workers: bool = True,
                   seed: int = 0, overrides: dict | None = None) -> GenerateBench:
    """Measure the pipeline (1 and 2 workers), its CPU time and raw MuJoCo on the same scenes (fast profile).

    One worker and raw MuJoCo run twice each, in the order pipeline, raw, raw, pipeline (their ratio sees the
    same load); object loading, each scene made once (filling the on-disk caches of the objects it uses, such as
    collision hulls, which a first run computes) and one warm-up frame (GL context start-up) are outside the
    1-worker figures.
    The datasets are written under :func:`tempfile.gettempdir` (``$TMPDIR``), whose file-creation cost counts.
    ``overrides``: further generation values (dotted keys), e.g. the plain look of earlier releases.
    """
    from simtest.backend.threads import available_cores
    from simtest.generators.pipeline import load_objects, generate, prepare_scene

    cfg = GenerateConfig().replace(**{
        "objects": objects, "scenes": scenes, "frames_per_scene": frames_per_scene, "camera.width": width,
        "camera.height": height, "scene.objects_per_scene": [objects_per_scene, objects_per_scene],
        "render.profile": "fast", "seed": seed, **(overrides or {})})
    objs = load_objects(cfg)
    for scene_id in range(scenes):  # caches outside the timings: the scenes' meshes, collision hulls, symmetries
        prepare_scene(cfg, objs, scene_id)
    with tempfile.TemporaryDirectory(prefix="simtest-bench-") as tmp:
        generate(cfg.replace(scenes=1, frames_per_scene=1), os.path.join(tmp, "warm"), progress=False)
        pipe_s, raw_s, cpu_s, frames, by_thread = _one_worker(cfg, objs, Path(tmp))
        fps2 = fps2_wall = cpu2 = cpu2_scenes = None
        if two_workers:
            cpu0 = cpu_seconds(children=True)
            rep2 = generate(cfg.replace(workers=2), os.path.join(tmp, "w2"), progress=False)
            cpu2 = (cpu_seconds(children=True) - cpu0) * 1000.0 / max(1, rep2.frames_written)
            busy: dict[int, float] = {}
            for s in rep2.scenes:
                busy[s.worker] = busy.get(s.worker, 0.0) + s.seconds
            fps2 = rep2.frames_written / max(busy.values())
            fps2_wall = rep2.frames_per_second
            cpu2_scenes = sum(s.cpu_seconds for s in rep2.scenes) * 1000.0 / max(1, rep2.frames_written)
    return GenerateBench(width, height, objects_per_scene, scenes, frames_per_scene, frames / pipe_s,
                         frames / raw_s, fps2, fps2_wall, cpu_s * 1000.0 / frames, cpu2, available_cores(),
                         cpu2_scenes, _per_frame_by_thread(by_thread, cpu_s, frames))


def _per_frame_by_thread(by_thread: dict[str, float], cpu_s: float, frames: int) -> dict[str, float]:
    """CPU ms per frame by thread group, plus what the groups miss of the process's CPU time (threads that
    ended between two reads of :class:`ThreadCpu`) as "not attributed"."""
    if not by_thread:
        return {}
    out = {name: sec * 1000.0 / frames for name, sec in by_thread.items()}
    missing = (cpu_s - sum(by_thread.values())) * 1000.0 / frames
    if missing >= 0.05:
        out["not attributed"] = missing
    return out


@dataclass(frozen=True)
class ProfileRow:
    """One profile at one image size (seconds per annotated frame).

    Attributes:
        wall: Seconds per frame, 1 worker (its scenes' wall time over their frames).
        cpu: CPU seconds per frame, 1 worker (all threads of the process).
        wall_2workers: Seconds per frame of the machine with 2 workers: the busy time of the slower worker over
            all frames (each worker's first frame, with its start-up of the renderers, included); ``None`` when
            not measured.
        spp: Samples per pixel used (``pbr``; ``None`` for the rasterized profiles).
        variant: What rendered it: the Mitsuba variant and, on ``llvm_ad_rgb``, the libLLVM version and file
            (from the run's manifest; ``pbr`` only).
        stages: ``pbr`` only: wall seconds per frame of each path-tracer stage of the 1-worker run
            (:mod:`simtest.render.pbr_stages`), and ``"rest"``: the rest of the frame (rasterized depth and masks,
            cameras, the hand-off to annotation and writing; scene sampling and settling run ahead).
        scene_loads: ``pbr`` only: Mitsuba scenes loaded in the 1-worker run (one per settled scene).
    """

    profile: str
    width: int
    height: int
    wall: float
    cpu: float
    wall_2workers: float | None = None
    spp: int | None = None
    variant: str | None = None
    stages: dict[str, float] | None = None
    scene_loads: int | None = None

    @property
    def speedup_2workers(self) -> float | None:
        """Frames/s of 2 workers over frames/s of 1."""
        return None if not self.wall_2workers else self.wall / self.wall_2workers


@dataclass
class ProfileBench:
    """Seconds per annotated frame of the whole pipeline for each render profile and image size, 1 worker and
    (with two or more scenes) 2 workers, the same seed and scenes for every profile (:class:`ProfileRow`); CPU
    seconds (all threads of the process) are what a loaded machine changes least."""

    rows: list[ProfileRow]
    scenes: int
    frames_per_scene: int

    def table(self) -> str:
        lines = ["| profile | image size | s/frame (wall) | CPU s/frame | 2 workers: s/frame | 2 workers / 1 worker |",
                 "|---|---|---|---|---|---|"]
        for r in self.rows:
            name = f"{r.profile} ({r.spp} spp, denoised)" if r.profile == "pbr" else r.profile
            two = ("-", "-") if r.wall_2workers is None else (f"{r.wall_2workers:.2f}", f"{r.speedup_2workers:.2f}")
            lines.append(f"| {name} | {r.width}x{r.height} | {r.wall:.2f} | {r.cpu:.2f} | {two[0]} | {two[1]} |")
        variants = sorted({r.variant for r in self.rows if r.variant})
        if variants:
            from simtest.benchmarks.machine import cpu_name

            lines += ["", f"pbr path tracer: {'; '.join(variants)}; {self.scenes} scenes x {self.frames_per_scene} "
                          f"views per measurement; processor: {cpu_name()}"]
        staged = [r for r in self.rows if r.stages]
        if staged:
            names = list(staged[0].stages)
            lines += ["", "pbr frame by stage, 1 worker, wall s/frame (rest: rasterized depth and masks, cameras, "
                          "hand-off to annotation and writing)", "",
                      "| image size | " + " | ".join(names) + " | Mitsuba scenes loaded |",
                      "|---|" + "---|" * (len(names) + 1)]
            for r in staged:
                lines.append(f"| {r.width}x{r.height} | " + " | ".join(f"{r.stages[k]:.3f}" for k in names)
                             + f" | {r.scene_loads} |")
        return "\n".join(lines)

    def to_dict(self) -> dict:
        """The table as JSON-ready data: ``{"kind": "profiles", "scenes", "frames_per_scene", "rows": [...]}``
        (each row the fields of :class:`ProfileRow`; seconds per frame)."""
        from dataclasses import asdict

        return {"kind": "profiles", "scenes": self.scenes, "frames_per_scene": self.frames_per_scene,
                "rows": [asdict(r) for r in self.rows]}


def _variant_text(manifest: dict) -> str:
    """``llvm_ad_rgb (libLLVM 19.1.7, /usr/lib/...)`` from a manifest's recorded versions."""
    v = manifest.get("versions", {})
    lib = f" (libLLVM {v['libllvm_version']}, {v['libllvm']})" if v.get("libllvm") else ""
    return f"{v.get('mitsuba_variant', '?')}{lib}"


def _two_workers_seconds(cfg: GenerateConfig, out: str) -> float:
    """Seconds per frame of ``cfg`` made by 2 workers: the slower worker's busy time over all frames."""
    from simtest.generators.pipeline import generate

    rep = generate(cfg.replace(workers=2), out, progress=False)
    busy: dict[int, float] = {}
    for s in rep.scenes:
        busy[s.worker] = busy.get(s.worker, 0.0) + s.seconds
    return max(busy.values()) / rep.frames_written


def bench_profiles(profiles: list[str], sizes: list[tuple[int, int]], objects_per_scene: int = 10,
                   scenes: int = 2, frames_per_scene: int = 3, objects: str = "builtin",
                   pbr_spp: int | str = "auto", seed: int = 0, pbr_variant: str = "auto",
                   two_workers: bool = True) -> ProfileBench:
    """Seconds per frame (sampling, settling, rendering, annotation, writing; object loading and one warm-up
    frame per profile excluded) of each profile at each ``(width, height)``, measured in one run, with 1 worker
    and, when ``two_workers`` and ``scenes >= 2``, with 2. ``pbr_spp`` and ``pbr_variant`` are the
    ``render.pbr_spp`` / ``render.pbr_variant`` of the pbr runs."""
    import json

    from simtest.generators.pipeline import load_objects, generate

    rows = []
    for w, h in sizes:
        for profile in profiles:
            cfg = GenerateConfig().replace(**{
                "objects": objects, "scenes": scenes, "frames_per_scene": frames_per_scene, "camera.width": w,
                "camera.height": h, "scene.objects_per_scene": [objects_per_scene, objects_per_scene],
                "render.profile": profile, "render.pbr_spp": pbr_spp, "render.pbr_variant": pbr_variant,
                "seed": seed})
            load_objects(cfg)
            with tempfile.TemporaryDirectory(prefix="simtest-bench-") as tmp:
                # warm-up outside the timing: GL context, path tracer and denoiser start-up
                generate(cfg.replace(scenes=1, frames_per_scene=1), os.path.join(tmp, "warm"), progress=False)
                stages0 = process_stages().copy()
                cpu0 = cpu_seconds()
                rep = generate(cfg, os.path.join(tmp, "out"), progress=False)
                cpu = (cpu_seconds() - cpu0) / rep.frames_written
                stages = process_stages().since(stages0)
                two = _two_workers_seconds(cfg, os.path.join(tmp, "w2")) if two_workers and scenes >= 2 else None
                manifest = json.loads((Path(tmp) / "out" / "manifest.json").read_text())
                variant = _variant_text(manifest) if profile == "pbr" else None
            wall = sum(s.seconds for s in rep.scenes) / rep.frames_written
            spp = by_stage = loads = None
            if profile == "pbr":
                from simtest.render.pbr import auto_spp

                spp = auto_spp(w, h) if pbr_spp == "auto" else int(pbr_spp)
                by_stage = {k: round(v, 4) for k, v in stages.per_frame().items()}
                by_stage["rest"] = round(max(0.0, wall - sum(by_stage.values())), 4)
                loads = stages.loads
            rows.append(ProfileRow(profile, w, h, wall, cpu, two, spp, variant, by_stage, loads))
    return ProfileBench(rows, scenes, frames_per_scene)
