"""Running an estimator over a dataset's images: what it sees of one image (:func:`observation`), one guarded
call and its failure records (:func:`estimate_image`), and the scenes as units of work on a back end
(:func:`run_scene_shards`: this process, a local pool or Ray; results joined in scene order). Scoring and the
output files are :mod:`simtest.evaluation.run`'s.
"""

from __future__ import annotations

import logging
import pickle
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from simtest.backend import Backend, RunStats, run_units
from simtest.errors import ConfigError, EstimatorError
from simtest.estimators.base import Observation, prepare_estimator, reset_estimator
from simtest.estimators.registry import is_file_target, load_estimator
from simtest.estimators.guard import call_estimator, check_estimate, log_fault
from simtest.io import bop
from simtest.io.dataset import ImageRef, image_targets
from simtest.metrics.bop19 import VISIB_GT_MIN, ResultRow
from simtest.objects.loaders import load_dataset_objects

log = logging.getLogger(__name__)


def targets_needed(estimator: Any) -> str | None:
    """Why an (instantiated) estimator cannot run without being told the targets (the detection task, where
    ``Observation.target_obj_ids`` is ``None``), or ``None`` when it can. An explicit ``needs_targets``
    attribute decides; without one, ``needs_gt_masks`` (masks and boxes are given per target),
    ``needs_gt_init`` (first poses per target) or ``needs_gt`` mean it needs them. An oracle that detects
    declares ``needs_gt = True`` and ``needs_targets = False``: it is given ``gt_poses`` and ``gt_obj_ids``."""
    explicit = getattr(estimator, "needs_targets", None)
    if explicit is not None:
        return "it declares needs_targets = True" if explicit else None
    for attr in ("needs_gt_masks", "needs_gt_init", "needs_gt"):
        if getattr(estimator, attr, False):
            return f"it declares {attr} = True (ground truth given per target) and not needs_targets = False"
    return None


def observation(ref: ImageRef, objects, targets: str, width: int, height: int, needs_gt: bool,
                 gt_masks: bool = False, frame_index: int = -1,
                 initialised: set[int] | None = None,
                 task: str = "localization") -> tuple[Observation, list[tuple[int, bop.ImageGT]]]:
    """The estimator's view of one image: ground-truth masks and boxes only with ``gt_masks``, poses only with
    ``needs_gt`` (see the module doc); ``depth`` is None when the scene has no ``depth/``. With ``initialised``
    (a ``needs_gt_init`` estimator: the ``gt_id`` of the scene's targets already given a pose), the targets'
    track ids, and the ground-truth pose of each target not in it (then added). In the ``"detection"`` task no
    target id, count, mask or box is given; a ``needs_gt`` estimator (an oracle with ``needs_targets = False``)
    gets ``gt_poses`` and ``gt_obj_ids`` of the targets."""
    rgb = bop.read_image(ref.scene_dir, ref.im_id)
    depth = bop.read_depth(ref.scene_dir, ref.im_id, ref.info["depth_scale"]) if ref.has_depth else None
    tg = image_targets(ref, VISIB_GT_MIN)
    kw: dict[str, Any] = {}
    if task == "detection":
        if needs_gt:
            kw["gt_poses"] = tuple((g.T_cam_obj.R.copy(), g.T_cam_obj.t.copy()) for _, g in tg)
            kw["gt_obj_ids"] = tuple(g.obj_id for _, g in tg)
    elif targets == "gt-masks":
        kw["target_obj_ids"] = tuple(g.obj_id for _, g in tg)
        if gt_masks or needs_gt:  # where the dataset has none, the run refused estimators that need them
            if ref.has_masks:
                kw["masks"] = tuple(bop.read_mask(ref.gt_dir, ref.im_id, j, visible=True) for j, _ in tg)
            kw["boxes"] = tuple(tuple(int(v) for v in g.bbox_visib) for _, g in tg)
        if needs_gt:
            kw["gt_poses"] = tuple((g.T_cam_obj.R.copy(), g.T_cam_obj.t.copy()) for _, g in tg)
        if initialised is not None:
            kw["track_ids"] = tuple(j for j, _ in tg)
            kw["init_poses"] = tuple(None if j in initialised else (g.T_cam_obj.R.copy(), g.T_cam_obj.t.copy())
                                     for j, g in tg)
            initialised.update(j for j, _ in tg)
    obs = Observation(rgb=rgb, depth=depth, K=ref.info["K"].copy(), width=width, height=height, objects=objects,
                      scene_id=ref.scene_id, im_id=ref.im_id, frame_index=frame_index, **kw)
    return obs, tg


def _failure(ref: ImageRef, obj_id: Any, kind: str, message: str, exception_type: str = "",
             trace: str = "") -> dict[str, Any]:
    return {"scene_id": ref.scene_id, "im_id": ref.im_id, "obj_id": "" if obj_id is None else obj_id,
            "kind": kind, "message": message, "exception_type": exception_type, "traceback": trace}


def estimate_image(est: Any, obs: Observation, ref: ImageRef, known: set[int], timeout: float | None,
                    results: list[ResultRow], scales: list[float],
                    failures: list[dict[str, Any]], fail_fast: bool = False) -> tuple[float, bool]:
    """Run the estimator on one image; append its valid estimates to ``results`` (and their scales to
    ``scales``, which runs parallel to ``results``) and every fault to ``failures`` (with ``fail_fast``: raise :class:`EstimatorError` at the
    first). Returns the wall time of the call (s) and whether the image failed as a whole (a fault, or only
    invalid estimates)."""
    t0 = time.perf_counter()
    out, fault = call_estimator(est, obs, timeout)
    dt = time.perf_counter() - t0
    if fault is not None:
        log_fault(log, f"scene {ref.scene_id} image {ref.im_id}", fault, "failures.csv")
        failures.append(_failure(ref, None, fault.kind, fault.message, fault.exception_type, fault.trace_tail))
        if fail_fast:
            _stop(est, failures[-1], fault.trace)
        return dt, True
    for f in list(getattr(est, "last_failures", None) or []):
        failures.append(_failure(ref, f.get("obj_id"), "no-estimate", str(f.get("reason", ""))))
    valid = 0
    for i, element in enumerate(out):
        e, why = check_estimate(element, known, index=i)
        if why is not None:
            failures.append(_failure(ref, why.obj_id, "invalid-estimate", why.message))
            if fail_fast:
                _stop(est, failures[-1], "")
            continue
        valid += 1
        row = ResultRow(scene_id=ref.scene_id, im_id=ref.im_id, obj_id=e.obj_id, score=e.score, R=e.R, t=e.t,
                        time=dt)
        results.append(row)
        scales.append(float(e.scale))
    return dt, bool(out) and valid == 0


def _stop(est: Any, failure: dict[str, Any], trace: str) -> None:
    """Raise :class:`EstimatorError` for one ``failures`` row, with the estimator's full traceback."""
    where = f"scene {failure['scene_id']} image {failure['im_id']}"
    if failure["obj_id"] != "":
        where += f" object {failure['obj_id']}"
    raise EstimatorError(f"{type(est).__name__} failed on {where} ({failure['kind']}): {failure['message']}"
                         + (f"\n{trace.rstrip()}" if trace else ""))

# ---------------------------------------------------------------------------------------------------------
# Image shards: the units of work of a run
@dataclass(frozen=True)
class WorkerSetup:
    """What a worker needs besides the estimator and the objects: the dataset root, how targets are given,
    the image size (pixels), the time limit (s), ``fail_fast`` and whether the estimator is a tracker given
    each target's first ground-truth pose (``needs_gt_init``), and the task (``localization`` or ``detection``)."""

    root: str
    targets: str
    width: int
    height: int
    needs_gt: bool
    gt_masks: bool
    timeout: float | None
    fail_fast: bool
    gt_init: bool = False
    task: str = "localization"


@dataclass(frozen=True)
class _Shard:
    """One unit of work: the selected images of one scene, in frame order; ``index`` is its place in the run."""

    index: int
    refs: tuple[ImageRef, ...]


@dataclass
class _ShardResult:
    """What one shard gives back: its valid estimates, their scales (parallel to ``results``), its
    failure rows, the estimator's wall time per image (s) and the count of images that failed as a whole."""

    index: int
    results: list[ResultRow] = field(default_factory=list)
    scales: list[float] = field(default_factory=list)
    failures: list[dict[str, Any]] = field(default_factory=list)
    times: list[float] = field(default_factory=list)
    failed_images: int = 0


#: The estimator, objects and settings of the run this process is working for (set by :func:`_init_worker`,
#: or by the driver when the shards run in its own process).
_WORKER: dict[str, Any] = {}


def scene_shards(refs: Sequence[ImageRef]) -> list[_Shard]:
    """One shard per scene, its images in frame order. A whole scene in one unit keeps an estimator that carries
    state from frame to frame (a tracker) correct whichever worker runs it, and amortises the worker's
    estimator loading over the scene's images."""
    groups: list[list[ImageRef]] = []
    for ref in refs:
        if groups and groups[-1][-1].scene_dir == ref.scene_dir:
            groups[-1].append(ref)
        else:
            groups.append([ref])
    return [_Shard(i, tuple(g)) for i, g in enumerate(groups)]


def _init_worker(estimator: Any, options: dict[str, Any] | None, setup: WorkerSetup) -> None:
    """Load the estimator and the dataset's objects once per worker process."""
    objects = load_dataset_objects(Path(setup.root))
    _WORKER.clear()
    est = load_estimator(estimator, **(options or {}))
    prepare_estimator(est, objects)  # outside the per-image time limit
    _WORKER.update(est=est, objects=objects, known=set(objects.ids), setup=setup)


def _run_shard(shard: _Shard) -> _ShardResult:
    """Run the worker's estimator on the images of one shard (see :func:`estimate_image`)."""
    est, objects, known, s = _WORKER["est"], _WORKER["objects"], _WORKER["known"], _WORKER["setup"]
    out = _ShardResult(shard.index)
    reset_estimator(est)  # a shard is one scene: a new sequence
    initialised: set[int] = set()
    for frame, ref in enumerate(shard.refs):
        obs, _ = observation(ref, objects, s.targets, s.width, s.height, s.needs_gt, s.gt_masks, frame,
                              initialised if s.gt_init else None, s.task)
        dt, failed = estimate_image(est, obs, ref, known, s.timeout, out.results, out.scales, out.failures,
                                    s.fail_fast)
        out.times.append(dt)
        out.failed_images += failed
        if "on_image" in _WORKER:  # in this process only: the progress bar moves per image
            _WORKER["on_image"](dt, len(out.failures))
    return out


def _absolute(ref: ImageRef) -> ImageRef:
    """``ref`` with absolute folders."""
    return replace(ref, scene_dir=ref.scene_dir.resolve(),
                   label_dir=None if ref.label_dir is None else ref.label_dir.resolve())


def _portable(spec: Any) -> Any:
    """The estimator spec as a worker process can load it: a ``file.py:attr`` path made absolute (a Ray worker
    runs in another folder); an instance or callable must pickle.

    Raises:
        ConfigError: An instance that cannot be sent to worker processes.
    """
    if isinstance(spec, str):
        module, sep, attr = spec.rpartition(":")
        if sep and module and is_file_target(module):
            return f"{Path(module).expanduser().resolve()}:{attr}"
        return spec
    try:
        pickle.dumps(spec)
    except Exception as exc:  # noqa: BLE001 - any pickling failure means the same thing
        raise ConfigError(f"estimator {spec!r} cannot be sent to worker processes ({type(exc).__name__}: {exc}); "
                          "give it by name, 'module:attr' or 'path/to/file.py:attr', or use one worker") from exc
    return spec


def run_scene_shards(est: Any, spec: Any, options: dict[str, Any] | None, shards: list[_Shard], backend: Backend,
                stats: RunStats, progress: bool, setup: WorkerSetup, objects: Any
                ) -> tuple[list[ResultRow], list[float], list[dict[str, Any]], list[float], int]:
    """Run every shard on ``backend`` (in this process with the loaded ``est`` when the back end says so) and
    join their outputs in shard order, which is the image order of a sequential run.

    Returns:
        ``(results, their scales (parallel to results), failures, times per image in s, images failed as a
        whole)``.
    """
    from tqdm import tqdm

    in_process = backend.in_process(len(shards))
    init_args = () if in_process else (_portable(spec), options, setup)
    if not in_process:  # a Ray worker may run in another folder
        shards = [_Shard(s.index, tuple(_absolute(r) for r in s.refs)) for s in shards]
    done: dict[int, _ShardResult] = {}
    if in_process:
        prepare_estimator(est, objects)  # before the bar and outside the per-image time limit, as in a worker
    bar = tqdm(total=sum(len(s.refs) for s in shards), desc="eval", unit="img", disable=not progress,
               dynamic_ncols=True)
    if in_process:
        _WORKER.clear()
        _WORKER.update(est=est, objects=objects, known=set(objects.ids), setup=setup)
    totals = {"failures": 0, "seconds": 0.0, "images": 0, "shown": 0}  # running totals for the progress bar

    def show(failures: int, seconds: float, images: int) -> None:
        bar.update(images - totals["shown"])
        totals["shown"] = images
        if progress and images:
            bar.set_postfix(fail=failures, s_per_img=f"{seconds / images:.3f}")

    if in_process:  # a scene may be long (a real test set is often one scene): move per image
        def on_image(dt: float, shard_failures: int) -> None:
            totals["shard_s"] = totals.get("shard_s", 0.0) + dt
            totals["shard_n"] = totals.get("shard_n", 0) + 1
            show(totals["failures"] + shard_failures, totals["seconds"] + totals["shard_s"],
                 totals["images"] + totals["shard_n"])
        _WORKER["on_image"] = on_image
    try:
        for res in run_units(_run_shard, shards, backend, init=_init_worker, init_args=init_args, stats=stats):
            done[res.index] = res
            totals.update(failures=totals["failures"] + len(res.failures), seconds=totals["seconds"] + sum(res.times),
                          images=totals["images"] + len(res.times), shard_s=0.0, shard_n=0)
            show(totals["failures"], totals["seconds"], totals["images"])
    finally:
        bar.close()
        if in_process:
            _WORKER.clear()
    results: list[ResultRow] = []
    scales: list[float] = []
    failures: list[dict[str, Any]] = []
    times: list[float] = []
    for r in (done[i] for i in range(len(shards))):
        results += r.results
        scales += r.scales
        failures += r.failures
        times += r.times
    return results, scales, failures, times, sum(r.failed_images for r in done.values())
