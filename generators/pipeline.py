"""``generate()``: config + seed -> BOP dataset. Workers own whole scenes; scenes are written atomically.

Determinism: scene ``i`` draws everything from ``child_rng(seed, i, attempt)``, so its files do not depend on
which worker ran it, on how many workers there were, on the back end (``local`` or ``ray``,
:mod:`simtest.backend`) or on whether the run was resumed.
"""

from __future__ import annotations

import logging
import os
import platform
import shutil
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

import simtest
from simtest.backend import RUN_FIELDS, Backend, BackendError, RunStats, preflight, run_units
from simtest.errors import DatasetError
from simtest.generators.config import GenerateConfig, camera_file_values
from simtest.io.bop import SceneWriter, scene_dirs, write_camera_json
from simtest.io.bop_targets import TARGETS_BOP19, TARGETS_BOP24, write_targets
from simtest.io.dataset import WITHHELD
from simtest.io.files import atomic_write_json, prepare_out_dir
from simtest.objects.prepare import prepare_set
from simtest.rng import child_rng
from simtest.schema import config_changes

__all__ = ["generate", "GenerateReport", "SceneReport", "render_scene", "prepare_scene"]

#: Names this module no longer holds, and the module each lives in; they forward there.
MOVED = {"scene_cameras": "simtest.generators.recorder", "ViewsBehind": "simtest.generators.views_behind",
         "DenseViews": "simtest.generators.dense"}

MANIFEST = "manifest.json"

log = logging.getLogger(__name__)


@dataclass
class SceneReport:
    """What happened while making one scene."""

    scene_id: int
    frames: int
    attempts: int
    retry_reasons: list[str]
    removed: int
    settle_time: float
    at_rest: bool
    seconds: float
    worker: int = 0  # process id of the worker that made it
    cpu_seconds: float = 0.0  # CPU time of the making process, all threads (its only work while it made the scene)


@dataclass
class GenerateReport:
    """Summary of a ``generate`` run."""

    out_dir: Path
    scenes_total: int
    scenes_done: int
    scenes_skipped: int
    frames_written: int
    seconds: float
    scenes: list[SceneReport] = field(default_factory=list)
    run: RunStats = field(default_factory=RunStats)  # what the back end did (units retried, lost)

    @property
    def frames_per_second(self) -> float:
        return self.frames_written / self.seconds if self.seconds > 0 else 0.0

    @property
    def retried(self) -> list[SceneReport]:
        return [s for s in self.scenes if s.attempts > 1]


def _versions(cfg: GenerateConfig) -> dict[str, str]:
    import mujoco

    out = {"simtest": simtest.__version__, "mujoco": mujoco.__version__, "numpy": np.__version__,
           "python": platform.python_version()}
    if cfg.render.profile == "pbr":
        from simtest.render.pbr import renderer_versions

        out.update(renderer_versions(cfg.render.pbr_variant))  # the variant used (and its libLLVM)
    return out


def load_objects(cfg: GenerateConfig):
    from simtest.objects import load_object_set

    return load_object_set(cfg.objects, units=cfg.units, scale=cfg.scale)


def __getattr__(name: str) -> Any:
    """The moved names (:data:`MOVED`), from their module, with a DeprecationWarning."""
    if name in MOVED:
        import importlib
        import warnings

        warnings.warn(f"simtest.generators.pipeline.{name} moved to {MOVED[name]}.{name}", DeprecationWarning,
                      stacklevel=2)
        return getattr(importlib.import_module(MOVED[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


# ---------------------------------------------------------------------------------------------------------
# One scene (runs in a worker)
_WORKER: dict = {}


def _worker_init(cfg_dict: dict) -> None:
    from simtest.backend.threads import worker_threads

    cfg = GenerateConfig.from_dict(cfg_dict)
    worker_threads(cfg.workers, cfg.ray_address, apply=True)  # its share of the cores (llvmpipe, OpenCV), before any render
    _WORKER["cfg"] = cfg
    _WORKER["objects"] = load_objects(cfg)


def prepare_scene(cfg: GenerateConfig, objects, scene_id: int):
    """Sample, build and settle scene ``scene_id``, re-sampling (new sub-seed) when it cannot be used.

    Returns:
        ``(scene, settle_result, attempts, reasons)``.

    Raises:
        DatasetError: If no attempt out of ``cfg.scene.max_attempts`` gave a usable scene.
    """
    from simtest.generators.builder import SceneBuilder
    from simtest.generators.scene_spec import PlacementError, sample_scene_spec
    from simtest.generators.settle import settle

    builder = SceneBuilder(objects, cfg.build_options())
    settling = cfg.settle_options()
    reasons: list[str] = []
    for attempt in range(cfg.scene.max_attempts):
        rng = child_rng(cfg.seed, scene_id, attempt)
        try:
            spec = sample_scene_spec(cfg, objects, rng, scene_id, attempt)
        except PlacementError as exc:
            reasons.append(str(exc))
            continue
        scene = builder.build(spec, rng)  # views and wrist configurations continue this stream
        result = settle(scene, settling)
        if not any(scene.active):
            reasons.append(f"scene {scene_id} attempt {attempt}: every object fell off the table")
            continue
        return scene, result, attempt + 1, reasons
    raise DatasetError(f"scene {scene_id}: no usable scene in {cfg.scene.max_attempts} attempts "
                       f"(scene.max_attempts); reasons: {'; '.join(reasons)}")


def render_scene(cfg: GenerateConfig, objects, scene_id: int, split_dir: Path,
                 prepared: tuple | None = None, finish_behind: bool = True) -> SceneReport:
    """Make scene ``scene_id`` and write it under ``split_dir`` (atomically, as a whole).

    Args:
        prepared: The scene's :func:`prepare_scene` result when it was made ahead (see :class:`ScenesAhead`);
            the same as making it here.
        finish_behind: Annotate and write each view on a helper thread while the next one renders
            (:class:`~simtest.generators.views_behind.ViewsBehind`); ``False`` finishes each view before the next
            (the same files, one thread).
    """
    from simtest.backend.threads import worker_threads
    from simtest.generators.recorder import SceneRecorder, scene_cameras

    t0, cpu0 = time.perf_counter(), time.process_time()
    scene, settled, attempts, reasons = prepared if prepared is not None else prepare_scene(cfg, objects, scene_id)
    cameras = scene_cameras(cfg, scene)
    writer = SceneWriter(split_dir, scene_id, depth_scale=cfg.render.depth_scale,
                         rgb_format=cfg.render.rgb_format, jpg_quality=cfg.render.jpg_quality, coco=cfg.render.coco,
                         coco_bbox=cfg.render.coco_bbox, coco_categories=objects.ids,
                         threads=worker_threads(cfg.workers, cfg.ray_address).writers)
    try:
        recorder = SceneRecorder(cfg, objects, scene, writer, scene_id)
        recorder.record(cameras, finish_behind)
        report = SceneReport(scene_id, len(cameras), attempts, reasons, len(settled.removed), settled.sim_time,
                             settled.at_rest, time.perf_counter() - t0, os.getpid())
        recorder.write_records(settled, attempts, reasons, cameras[0][0])
        writer.close(labels_dir=withheld_dir(split_dir, scene_id) if cfg.unlabelled else None)
    except BaseException:  # a scene is written whole or not at all: no partial folder is left behind
        writer.discard()
        raise
    report.cpu_seconds = time.process_time() - cpu0
    return report


def withheld_dir(split_dir: Path, scene_id: int) -> Path:
    """Where an unlabelled split's scene ``scene_id`` keeps its labels: ``<out>/withheld/<split>/<scene>``."""
    return split_dir.parent / WITHHELD / split_dir.name / f"{scene_id:06d}"


def _worker_scene(args: tuple[int, str]) -> SceneReport:
    scene_id, split_dir = args
    return render_scene(_WORKER["cfg"], _WORKER["objects"], scene_id, Path(split_dir))


# ---------------------------------------------------------------------------------------------------------
def _check_out_dir(out: Path, cfg: GenerateConfig, resume: bool, overwrite: bool) -> None:
    """The output-folder rule (:func:`simtest.io.files.prepare_out_dir`) plus what a resume must match."""
    if not (resume or overwrite) and out.is_dir() and not (out / MANIFEST).exists() and _only_generated(out, cfg):
        raise DatasetError(f"dataset folder {str(out)!r} holds an interrupted generation (no {MANIFEST}, "
                           f"{_count_scenes(out / cfg.split)}); pass --resume to continue it or --overwrite to "
                           f"start again")
    if not prepare_out_dir(out, overwrite=overwrite, resume=resume, can_resume=True, clear=True,
                           what="dataset folder"):
        return
    manifest = out / MANIFEST
    if not manifest.is_file():
        if not _only_generated(out, cfg):
            foreign = sorted(p.name for p in out.iterdir() if not _is_generated(p.name, cfg))
            raise DatasetError(f"cannot resume into {str(out)!r}: it has no {MANIFEST} and holds files generate "
                               f"does not write ({', '.join(foreign[:5])}); not a simtest dataset")
        log.warning("resuming %s without %s: its complete scenes are kept as made with this config", out, MANIFEST)
        return
    import json

    diffs = config_changes(json.loads(manifest.read_text())["config"], cfg.to_dict(), GenerateConfig().to_dict(),
                           ignore=RUN_FIELDS)
    if diffs:
        raise DatasetError(f"cannot resume into {str(out)!r}: its config differs from this run's at "
                           f"{', '.join(diffs[:8])}; use the same config (or --overwrite)")


def _is_generated(name: str, cfg: GenerateConfig) -> bool:
    """Whether a top-level entry of a dataset folder is one ``generate`` writes (or its atomic temporary)."""
    return name in (MANIFEST, "camera.json", "models", cfg.split, WITHHELD, TARGETS_BOP19, TARGETS_BOP24) or (
        name.startswith(".") and name.endswith(".tmp"))


def _only_generated(out: Path, cfg: GenerateConfig) -> bool:
    entries = list(out.iterdir())
    return bool(entries) and all(_is_generated(p.name, cfg) for p in entries)


def _count_scenes(split_dir: Path) -> str:
    done = len(scene_dirs(split_dir)) if split_dir.is_dir() else 0
    partial = len(list(split_dir.glob(".*.partial"))) if split_dir.is_dir() else 0
    return f"{done} complete and {partial} partial scene folders"


def generate(cfg: GenerateConfig, out_dir: str | Path, *, resume: bool = False, overwrite: bool = False,
             progress: bool = True, command_line: list[str] | None = None) -> GenerateReport:
    """Generate a BOP dataset.

    Args:
        cfg: Validated config (``cfg.seed`` and ``cfg.workers`` included).
        out_dir: Dataset folder. Must be empty or absent unless ``resume`` or ``overwrite``.
        resume: Continue an interrupted run: complete scenes are kept, the rest are made.
        overwrite: Delete ``out_dir`` first.
        progress: Show a progress bar (frames/s, ETA) on stderr.
        command_line: Recorded in the manifest (defaults to ``sys.argv``).

    Raises:
        DatasetError: Non-empty output without ``resume``/``overwrite``, or a resume with another config.
    """
    out = Path(out_dir)
    camera = cfg.build_options().camera  # the dataset's intrinsics (camera.json); every scene's camera has them
    if cfg.render.profile == "pbr":  # fail before touching the output when the extra is missing
        from simtest.render.pbr import require_pbr, resolved_variant

        require_pbr(camera, cfg.render.pbr_variant)
        # every worker renders with the variant this process resolved (the same bytes with 1 or N workers)
        cfg = cfg.replace(**{"render.pbr_variant": resolved_variant(cfg.render.pbr_variant)})
    preflight(Backend.of(cfg))  # before the output is touched
    _check_out_dir(out, cfg, resume, overwrite)
    t0 = time.perf_counter()
    objects = load_objects(cfg)
    if not getattr(objects, "lazy", False):  # collision parts decomposed here, under a bar, not in each worker
        prepare_set(objects, progress=None if progress else False)
    if cfg.scene.distractor_objects:  # a bad set stops here, before the output exists; parts decomposed once
        from simtest.generators.distractor_objects import distractor_object_set

        prepare_set(distractor_object_set(cfg.scene.distractor_objects), progress=None if progress else False)
    if cfg.captions:
        from simtest.generators.captions import check_caption_objects

        check_caption_objects(objects)
    out.mkdir(parents=True, exist_ok=True)
    split_dir = out / cfg.split
    split_dir.mkdir(exist_ok=True)
    if not (out / MANIFEST).exists():
        atomic_write_json(out / MANIFEST, {
            "format": "bop-scenewise", "generator": "simtest", "versions": _versions(cfg), "seed": cfg.seed,
            "config": cfg.to_dict(), "object_set": objects.name, "objects": [
                {"obj_id": e.obj_id, "name": e.name, "category": e.category, "source": e.source}
                for e in objects.entries],
            "command_line": list(command_line if command_line is not None else sys.argv),
            "unlabelled": cfg.unlabelled, "captions": cfg.captions,
            "units": {"poses": "mm (BOP)", "depth": f"uint16, mm = value * {cfg.render.depth_scale}"},
            **({} if cfg.camera.file is None else {"camera_file": {  # its path and the values read from it
                "path": cfg.camera.file, "values": camera_file_values(cfg.camera.file)}})})
    write_camera_json(out / "camera.json", camera, cfg.render.depth_scale)
    _write_models(objects, out / "models", split_dir)
    if "keypoints" in cfg.annotation.channels:
        from simtest.io.bop_models import write_models_keypoints

        write_models_keypoints(objects, out / "models")
    done = {int(p.name) for p in scene_dirs(split_dir)}
    todo = [i for i in range(cfg.scenes) if i not in done]
    for partial in split_dir.glob(".*.partial"):
        shutil.rmtree(partial, ignore_errors=True)
    report = GenerateReport(out, cfg.scenes, 0, len(done), 0, 0.0)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(todo) * cfg.frames_per_scene, unit="frame", desc="generate", dynamic_ncols=True,
                   smoothing=0.1, file=sys.stderr)
    failed = True
    try:
        run_scenes(cfg, objects, todo, split_dir, report, bar)
        _write_models(objects, out / "models", split_dir, scenes_done=True, unlabelled=cfg.unlabelled)
        write_targets(out, [(int(d.name), withheld_dir(split_dir, int(d.name)) if cfg.unlabelled else d)
                            for d in scene_dirs(split_dir)])
        failed = False
    finally:
        if bar is not None:
            bar.close()
        report.seconds = time.perf_counter() - t0
        try:
            _record_run(out / MANIFEST, cfg, report)
        except OSError:
            if not failed:
                raise
            log.debug("the run record could not be written after the run failed", exc_info=True)  # keep the cause
    report.scenes.sort(key=lambda s: s.scene_id)
    return report


def run_scenes(cfg: GenerateConfig, objects, todo: list[int], split_dir: Path, report: GenerateReport,
                bar) -> None:
    """Make the scenes ``todo`` where ``cfg.backend`` says, accounting each in ``report`` as it finishes.

    Raises:
        BackendError: Scenes lost with their workers more often than the retries allow; it names them and says
            that ``--resume`` makes them (every other scene is written).
    """
    backend = Backend.of(cfg)
    ahead = ScenesAhead(cfg, objects, todo) if backend.in_process(len(todo)) else None
    if ahead is not None:
        def fn(unit: tuple[int, str]) -> SceneReport:  # this process: its objects are loaded already
            return render_scene(cfg, objects, unit[0], Path(unit[1]), prepared=ahead.take(unit[0]))
    else:
        fn = _worker_scene
    units = [(i, str(split_dir.resolve())) for i in todo]  # absolute: a worker's working folder may differ
    try:
        # a worker gets the camera file's values, not its path (which may not exist where the worker runs)
        init_args = (cfg.to_dict(camera_file=False),)
        for rep in run_units(fn, units, backend, init=_worker_init, init_args=init_args, stats=report.run):
            _account(report, rep, bar)
    except BackendError as exc:
        if not report.run.failures:
            raise
        lost = sorted(f.unit[0] for f in report.run.failures)
        raise BackendError(f"{len(lost)} scene(s) of {str(split_dir.parent)!r} were not made, their workers were "
                           f"lost more than {backend.retries} time(s): scene ids {', '.join(map(str, lost[:20]))}"
                           f"{' ...' if len(lost) > 20 else ''}; the other scenes are written: run the same command "
                           f"with --resume to make the missing ones ({report.run.failures[0].message})") from exc
    finally:
        if ahead is not None:
            ahead.close()


class ScenesAhead:
    """Builds and settles the next scene on a helper thread while this process renders the current one.

    One worker rendering in its own process leaves part of a second core idle between its serial steps; the
    next scene's sampling, compilation and physics settling (:func:`prepare_scene`: no GL, its own seeded
    stream, MuJoCo's physics releasing the GIL) fill it. Scenes are taken in ``order``; the result is the same
    as preparing each one when it is rendered.
    """

    #: Name prefix of the helper thread (benchmarks group CPU time by it).
    THREAD_NAME = "simtest-scene-ahead"

    def __init__(self, cfg: GenerateConfig, objects, order: list[int]) -> None:
        from concurrent.futures import ThreadPoolExecutor

        self._cfg, self._objects, self._order = cfg, objects, list(order)
        self._position = {scene_id: k for k, scene_id in enumerate(self._order)}
        self._pool = ThreadPoolExecutor(1, thread_name_prefix=self.THREAD_NAME)
        self._futures: dict[int, Any] = {}
        self._submit(0)

    def _submit(self, k: int) -> None:
        if k < len(self._order) and self._order[k] not in self._futures:
            scene_id = self._order[k]
            self._futures[scene_id] = self._pool.submit(prepare_scene, self._cfg, self._objects, scene_id)

    def take(self, scene_id: int) -> tuple:
        """The :func:`prepare_scene` result of ``scene_id`` (made ahead, or now); starts the next one."""
        k = self._position[scene_id]
        self._submit(k)
        future = self._futures.pop(scene_id)
        self._submit(k + 1)
        return future.result()

    def close(self) -> None:
        for future in self._futures.values():
            future.cancel()
        self._pool.shutdown(wait=True)


def _record_run(manifest: Path, cfg: GenerateConfig, report: GenerateReport) -> None:
    """Append what this run did (back end, scenes made, units retried and lost, seconds) to the manifest's
    ``runs`` list (a resumed dataset lists every run that made part of it)."""
    import json

    if not manifest.is_file():
        return
    data = json.loads(manifest.read_text())
    stats = report.run
    data.setdefault("runs", []).append({  # where it ran: workers only where they applied (not a joined cluster)
        **stats.record(cfg.workers), "backend": cfg.backend, "ray_address": cfg.ray_address,
        "scenes_made": report.scenes_done, "scenes_skipped": report.scenes_skipped, "retried": stats.retried,
        "lost": sorted(f.unit[0] for f in stats.failures), "seconds": round(report.seconds, 3)})
    atomic_write_json(manifest, data)


def _write_models(objects, models_dir: Path, split_dir: Path, scenes_done: bool = False,
                  unlabelled: bool = False) -> None:
    """Write the BOP ``models/`` folder: every object of the set, before the scenes; for a lazily read set
    (a large mesh library, :class:`~simtest.objects.lazy.LazyObjectSet`) only the objects the written scenes
    use (read from their ``scene_gt.json``, withheld for an ``unlabelled`` split), after them, so a set's size
    does not add to the cost of its scenes."""
    from simtest.io.bop import read_json
    from simtest.io.bop_models import INFO_FILE, write_bop_models
    info = models_dir / INFO_FILE
    if not objects.lazy:
        if not scenes_done and not info.exists():
            write_bop_models(objects, models_dir)
        return
    if not scenes_done:
        return
    labels = [withheld_dir(split_dir, int(d.name)) if unlabelled else d for d in scene_dirs(split_dir)]
    used = {int(g["obj_id"]) for d in labels for gts in read_json(d / "scene_gt.json").values() for g in gts}
    have = {int(k) for k in read_json(info)} if info.exists() else set()
    if used - have:
        write_bop_models(objects.subset(sorted(used | have)), models_dir)


def _account(report: GenerateReport, rep: SceneReport, bar) -> None:
    report.scenes.append(rep)
    report.scenes_done += 1
    report.frames_written += rep.frames
    if bar is not None:
        bar.update(rep.frames)
        if rep.attempts > 1:
            bar.write(f"scene {rep.scene_id}: re-sampled {rep.attempts - 1}x ({rep.retry_reasons[-1]})")
