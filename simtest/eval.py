"""Run a pose estimator over a BOP dataset and score it; or score an existing BOP results CSV.

:func:`evaluate` iterates the images of a split, builds one :class:`~simtest.estimators.base.Observation` per
image, calls the estimator through :func:`simtest.estimators.guard.call_estimator` (timing it, with a per-image
time limit; an exception, ``sys.exit``, a timeout or a return value that is not a list is recorded and the run
goes on), rejects invalid estimates (:func:`~simtest.estimators.guard.check_estimate`: not PoseEstimate-like,
wrong shapes, NaN / inf, not a rotation, unknown object id), writes the estimates as a BOP results CSV and
scores them with :func:`score_estimates`. :func:`score_results` scores a results CSV written by any
estimator, with the same code, so both give the same numbers.

Scoring protocol
----------------
* **Targets** are the ground-truth instances with ``visib_fract >= 0.1`` (BOP19's ``visib_gt_min``). With
  ``targets="gt-masks"`` the estimator is told their object ids (one per instance, as BOP's localisation
  task); their ground-truth visible masks and boxes only if it declares ``needs_gt_masks`` (such runs are
  labelled ``NAME (GT masks)``), their poses only if it declares ``needs_gt`` (the ``oracle``). Any other
  estimator reads no ground truth: no mask file is opened for it.
* **Matching** (for the per-target errors): per image and object id, estimates in order of decreasing score
  are each assigned to the not yet assigned target with the nearest translation (``te``); at most one estimate
  per target. A target left without an estimate is a **miss**: its distances count as infinite, its rotation
  error as pi. Estimates left over are false positives (counted, not scored by these metrics).
* **Per-target errors** (``errors.csv``, metres / degrees / pixels): ``add``, ``adi`` (ADD-S),
  ``add_s_or_add`` (ADD-S for symmetric objects, else ADD), ``re`` (geodesic, degrees), ``re_sym`` (the
  smallest ``re`` over the object's symmetry set, equal to ``re`` for non-symmetric objects), ``te`` (metres),
  ``mssd`` (metres), ``mspd`` (pixels of a 640 px wide image), ``vsd`` (mean VSD error over BOP19's taus; only
  with ``vsd=True``).
* **Aggregates** (per object and overall, pooled over targets): ADD(-S)-0.1d accuracy; YCB-Video AUC of
  ADD-S and of ADD(-S) (VOC-style rule, 0 to 0.10 m, :func:`simtest.metrics.auc.ycb_auc`); ADD-S < 2 cm;
  Acc@pi/6, Acc@pi/18 and median rotation error (``re_sym``; the viewpoint protocol, misses = pi); median
  translation error; n deg m cm accuracies (``re_sym``, ``te``, inclusive) at (5, 2), (5, 5), (10, 2),
  (10, 5); BOP19 AR (:func:`simtest.metrics.bop19.evaluate_bop19`: AR_VSD, AR_MSSD, AR_MSPD and their mean;
  without VSD the AR is the mean of AR_MSSD and AR_MSPD and is labelled so); mean time per image.
  BOP19 is evaluated image by image; pooled recalls are exact because each recall is a count of matched
  targets, so the per-image ARs weighted by their target counts add up to the pooled AR.
* **Per category** (when the dataset's objects fall into categories: more than one, fewer than objects): the
  same aggregates pooled over the targets of each category's objects, Acc@pi/6 and Acc@pi/18 among them
  (the compositional / viewpoint protocol, ``e = ||logm(R_p^T R_gt)||_F / sqrt(2)`` over the symmetry set);
  ``metrics.json`` ``per_category`` and a category table in ``metrics.md``.

Parallel runs
-------------
With a ``backend`` (:mod:`simtest.backend`: a local pool or Ray) the unit of work is one scene, its images in
frame order; each worker process loads the estimator and the objects once. The workers send back their rows
and the driver writes them in scene and image order, so the files are those of a one-worker run except the
measured times (``results.csv`` ``time``, ``*_time_per_image_s``) and the ``backend`` / ``workers`` settings.

Outputs (``out_dir``): ``results.csv`` (BOP format, t in mm), ``metrics.json``, ``errors.csv`` (one row per
target), ``failures.csv`` (image, object, kind, message, exception type, the last frames of the estimator's
traceback) and ``metrics.md`` (Markdown tables, units in the column headers).
"""

from __future__ import annotations

import json
import logging
import pickle
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from simtest.backend import Backend, RunStats, run_units
from simtest.errors import ConfigError, EstimatorError
from simtest.estimators.base import (GT_INIT_LABEL, GT_MASKS_LABEL, Estimator, Observation, _is_file_target,
                                     gt_access, load_estimator, needs_gt_init, reset_estimator)
from simtest.eval_tracking import TrackingReport, is_sequence_dataset, score_tracking, write_tracking
from simtest.estimators.guard import DEFAULT_TIMEOUT_S, call_estimator, check_estimate, check_timeout
from simtest.io import bop
from simtest.io.bop_results import read_bop_results, write_bop_results
from simtest.io.dataset import ImageRef, image_size, image_targets, select_images
from simtest.io.files import atomic_write_text, csv_text, jsonable, prepare_out_dir
from simtest.metrics.bop19 import VISIB_GT_MIN, ResultRow
from simtest.metrics.registry import NDEG_MCM, definitions
from simtest.objects.loaders import load_dataset_objects
from simtest.scoring import aggregate_by_category, has_categories, score_estimates
from simtest.tables import failure_counts, format_table, overall_table

__all__ = ["EvalReport", "evaluate", "score_results", "score_estimates", "load_dataset_objects", "TARGET_MODES",
           "NDEG_MCM", "format_table", "overall_table", "failure_counts"]

log = logging.getLogger(__name__)

#: How targets are given to the estimator.
TARGET_MODES = ("gt-masks", "none")


# ---------------------------------------------------------------------------------------------------------
# Report
@dataclass
class EvalReport:
    """Scores of one evaluation.

    Attributes:
        overall: Aggregate metrics over all targets (see the module doc; distances in metres, angles in
            degrees where the key says ``_deg``, fractions in [0, 1]).
        per_object: ``{obj_id: metrics}`` with the same keys.
        errors: One dict per target (``errors.csv`` rows).
        failures: One dict per failure (``failures.csv`` rows): ``scene_id, im_id, obj_id, kind, message,
            exception_type, traceback`` (the last frames, one line).
        estimates: The valid estimates, as BOP result rows (metres).
        object_names: ``{obj_id: name}``.
        num_images: Images evaluated.
        paths: Files written (``results``, ``metrics``, ``errors``, ``failures``, ``table``).
        settings: What was evaluated (dataset, split, estimator, targets, vsd).
        num_failed_images: Images on which the estimator failed as a whole (raised, exited, timed out,
            returned no list, or returned only invalid estimates).
        per_category: ``{category: metrics}`` (the per-object keys plus ``num_objects``) when the dataset's
            objects fall into categories (:func:`simtest.scoring.has_categories`), else empty.
        tracking: The tracking scores of a sequence evaluation (:mod:`simtest.eval_tracking`), else ``None``.
    """

    overall: dict[str, Any]
    per_object: dict[int, dict[str, Any]]
    errors: list[dict[str, Any]]
    failures: list[dict[str, Any]]
    estimates: list[ResultRow]
    object_names: dict[int, str]
    num_images: int
    paths: dict[str, Path] = field(default_factory=dict)
    settings: dict[str, Any] = field(default_factory=dict)
    num_failed_images: int = 0
    per_category: dict[str, dict[str, Any]] = field(default_factory=dict)
    tracking: TrackingReport | None = None

    def all_images_failed(self) -> bool:
        """Whether the estimator failed on every image (raised, exited, timed out, returned no list, or
        returned only invalid estimates): a run that measured nothing."""
        return self.num_images > 0 and self.num_failed_images == self.num_images

    def failure_summary(self) -> str:
        """One line: how many images failed, by kind, and the first failure's message."""
        kinds = ", ".join(f"{k} {n}" for k, n in failure_counts(self.failures).items())
        first = " ".join(self.failures[0]["message"].split()) if self.failures else ""
        return (f"the estimator failed on {self.num_failed_images} of {self.num_images} images ({kinds}); "
                f"first: {first}")

    def table(self) -> str:
        """Markdown tables (per object and overall), ready to paste."""
        return format_table(self)

    def to_json(self) -> dict[str, Any]:
        return {"settings": self.settings, "num_images": self.num_images, "overall": jsonable(self.overall),
                "per_object": {str(k): {"name": self.object_names.get(k, str(k)), **jsonable(v)}
                               for k, v in sorted(self.per_object.items())},
                **({"per_category": {k: jsonable(v) for k, v in self.per_category.items()}}
                   if self.per_category else {}),
                "num_failures": len(self.failures), "failures_by_kind": failure_counts(self.failures),
                "definitions": METRIC_DEFINITIONS}


#: Definitions written into ``metrics.json`` (from :mod:`simtest.metrics.registry`).
METRIC_DEFINITIONS = definitions()


# ---------------------------------------------------------------------------------------------------------
# Running an estimator
def _observation(ref: ImageRef, objects, targets: str, width: int, height: int, needs_gt: bool,
                 gt_masks: bool = False, frame_index: int = -1,
                 initialised: set[int] | None = None) -> tuple[Observation, list[tuple[int, bop.ImageGT]]]:
    """The estimator's view of one image: ground-truth masks and boxes only with ``gt_masks``, poses only with
    ``needs_gt`` (see the module doc). With ``initialised`` (a ``needs_gt_init`` estimator: the ``gt_id`` of the
    scene's targets already given a pose), the targets' track ids, and the ground-truth pose of each target not
    in it (then added)."""
    rgb = bop.read_image(ref.scene_dir, ref.im_id)
    depth = bop.read_depth(ref.scene_dir, ref.im_id, ref.info["depth_scale"])
    tg = image_targets(ref, VISIB_GT_MIN)
    kw: dict[str, Any] = {}
    if targets == "gt-masks":
        kw["target_obj_ids"] = tuple(g.obj_id for _, g in tg)
        if gt_masks or needs_gt:
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


def evaluate(dataset_dir: str | Path, estimator: str | Estimator | Any, *, split: str = "train_pbr",
             targets: str = "gt-masks", scenes: Sequence[int] | None = None, max_images: int | None = None,
             progress: bool = True, out_dir: str | Path | None = None, vsd: bool = True,
             estimator_options: dict[str, Any] | None = None,
             timeout: float | None = DEFAULT_TIMEOUT_S, overwrite: bool = False,
             fail_fast: bool = False, labels: str | Path | None = None, tracking: bool | None = None,
             backend: Backend | None = None, stats: RunStats | None = None) -> EvalReport:
    """Run ``estimator`` on every selected image of a BOP dataset and score it.

    Args:
        dataset_dir: BOP dataset root (with ``models/`` or a manifest naming the object set).
        estimator: A name (``oracle``, ``icp``, ``umeyama``), ``"module:attr"``, an instance with
            ``estimate(observation)`` or a callable; see :func:`simtest.estimators.load_estimator`.
        split: Split folder (``train_pbr``).
        targets: ``"gt-masks"``: tell the estimator the targets' object ids, and their ground-truth visible
            masks and boxes if it declares ``needs_gt_masks`` (the run is then labelled ``NAME (GT masks)``);
            ``"none"``: nothing, the estimator finds objects itself (one that cannot, e.g. ``icp``, fails).
            Ground-truth poses are passed only to estimators with ``needs_gt = True`` (the ``oracle``), and
            only with ``"gt-masks"``.
        scenes: Scene ids to evaluate (default all).
        max_images: Evaluate only the first N images.
        progress: Show a tqdm progress bar.
        out_dir: Write ``results.csv``, ``metrics.json``, ``errors.csv``, ``failures.csv``, ``metrics.md``.
        vsd: Also compute VSD (per-target errors and AR_VSD); about 5-10 ms per estimate at 320x240.
        estimator_options: Options for a named estimator (ignored for instances).
        timeout: Time limit of one ``estimate()`` call, seconds (``None`` or 0: no limit); an image over the
            limit is recorded as a ``timeout`` failure and the run goes on with the next image.
        overwrite: Allow a non-empty ``out_dir`` (its files of these names are replaced); checked before the
            estimator is loaded. ``out_dir`` may never be, or lie inside, ``dataset_dir``.
        fail_fast: Stop at the first fault of the estimator (any failure kind but ``no-estimate``) by raising
            :class:`~simtest.errors.EstimatorError` with its traceback; nothing is written.
        labels: Folder of withheld labels (``<labels>/<split>/<scene>/scene_gt.json`` and masks) for a split
            without them; default ``<dataset>/withheld`` when the manifest says ``"unlabelled": true``
            (:func:`simtest.io.dataset.labels_root`). Images and depth come from the split either way.
        tracking: Also score the run as tracking (:mod:`simtest.eval_tracking`: per-frame 3D IoU, n deg m cm,
            errors over time, frames tracked before loss; ``tracking.md``, ``tracking.csv``, ``tracking.png``
            in ``out_dir``). ``None``: when the dataset's manifest says ``rig = "sequence"``.
        backend: Where the images run (default: this process). Every worker loads the estimator and the
            objects once; a unit of work is one scene, its images in frame order (see :func:`_scene_shards`).
            The outputs are the same for every back end and worker count but for the measured times.
        stats: Filled with the units finished, retried and failed (:class:`simtest.backend.RunStats`).

    Returns:
        The :class:`EvalReport`.

    Raises:
        ConfigError: Unknown ``targets`` value or estimator, an estimator needing ground truth with
            ``targets="none"``, or a negative ``timeout``.
        EstimatorError: With ``fail_fast``, the estimator's first fault.
        DatasetError: Missing dataset folder, split or models, or malformed ground truth (an unknown
            ``obj_id``, a non-finite or non-rotation pose, missing scene files); checked before the estimator
            runs. ``out_dir`` not empty without ``overwrite``, not writable, or inside ``dataset_dir``.

    Estimator faults never end the run: an image where the estimator raises (kind ``exception``), calls
    ``sys.exit`` (``exit``), exceeds ``timeout`` (``timeout``) or returns something other than a list
    (``invalid-return``) is recorded in ``failures.csv`` and its targets count as misses; an invalid element of
    the returned list is recorded as ``invalid-estimate`` and dropped. ``KeyboardInterrupt`` stops the run. An
    estimator may also expose ``last_failures``: a list of ``{"obj_id", "reason"}`` dicts describing the
    targets it gave up on in its last call; they are recorded with kind ``no-estimate``.
    """
    if targets not in TARGET_MODES:
        raise ConfigError(f"targets must be one of {', '.join(TARGET_MODES)}, got {targets!r}")
    root = Path(dataset_dir)
    _check_out(out_dir, root, overwrite)
    est = load_estimator(estimator, **(estimator_options or {}))
    gt_masks, needs_gt = gt_access(est)
    gt_init = needs_gt_init(est)
    if (needs_gt or gt_init) and targets == "none":
        raise ConfigError(f"estimator {estimator!r} needs ground-truth targets (needs_gt or needs_gt_init = True); "
                          "use targets='gt-masks'")
    gt_masks = gt_masks and targets == "gt-masks"
    limit = check_timeout(timeout)
    objects = load_dataset_objects(root)
    known = set(objects.ids)
    refs = select_images(root, split, scenes, max_images, known, labels)
    width, height = image_size(root)
    backend = backend if backend is not None else Backend()
    stats = stats if stats is not None else RunStats()
    run = _run_shards(est, estimator, estimator_options, _scene_shards(refs), backend, stats, progress,
                      _WorkerSetup(str(root.resolve()), targets, width, height, needs_gt, gt_masks, limit, fail_fast,
                                   gt_init),
                      objects)
    results, scales, failures, times, failed_images = run
    overall, per_object, rows, names = score_estimates(root, results, objects=objects, vsd_enabled=vsd,
                                                       scales=scales, progress=False, _refs=refs)
    overall["num_images"] = len(refs)
    overall["num_estimates"] = len(results)
    overall["num_failures"] = len(failures)
    overall["num_image_exceptions"] = sum(f["kind"] == "exception" for f in failures)
    overall["mean_time_per_image_s"] = float(np.mean(times)) if times else float("nan")
    overall["median_time_per_image_s"] = float(np.median(times)) if times else float("nan")
    labelled = gt_masks and not needs_gt  # the oracle's name says it
    settings = {"dataset": str(root), "split": split,
                "estimator": _describe(estimator, est) + (GT_MASKS_LABEL if labelled else "")
                + (GT_INIT_LABEL if gt_init else ""),
                "gt_masks": labelled, "gt_init": gt_init, "targets": targets,
                "scenes": None if scenes is None else [int(s) for s in scenes], "max_images": max_images,
                "vsd": bool(vsd), "estimator_options": jsonable(estimator_options or {}), "timeout_s": limit,
                "labels": None if labels is None else str(labels), "backend": backend.name,
                "workers": backend.workers}
    report = EvalReport(overall=overall, per_object=per_object, errors=rows, failures=failures, estimates=results,
                        object_names=names, num_images=len(refs), settings=settings,
                        num_failed_images=failed_images, per_category=_per_category(objects, rows, per_object))
    if tracking or (tracking is None and is_sequence_dataset(root)):
        report.tracking = score_tracking(root, results, refs, objects, label=settings["estimator"])
    if out_dir is not None:
        _write_outputs(report, Path(out_dir), write_results=True)
    return report


def _estimate_image(est: Any, obs: Observation, ref: ImageRef, known: set[int], timeout: float | None,
                    results: list[ResultRow], scales: dict[int, float],
                    failures: list[dict[str, Any]], fail_fast: bool = False) -> tuple[float, bool]:
    """Run the estimator on one image; append its valid estimates to ``results`` (and non-unit scales to
    ``scales``) and every fault to ``failures`` (with ``fail_fast``: raise :class:`EstimatorError` at the
    first). Returns the wall time of the call (s) and whether the image failed as a whole (a fault, or only
    invalid estimates)."""
    t0 = time.perf_counter()
    out, fault = call_estimator(est, obs, timeout)
    dt = time.perf_counter() - t0
    if fault is not None:
        log.warning("estimator failed on scene %d image %d (%s): %s%s", ref.scene_id, ref.im_id, fault.kind,
                    fault.message, "\n" + fault.trace if fault.trace else "")
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
        if e.scale != 1.0:
            scales[id(row)] = e.scale
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
class _WorkerSetup:
    """What a worker needs besides the estimator and the objects: the dataset root, how targets are given,
    the image size (pixels), the time limit (s), ``fail_fast`` and whether the estimator is a tracker given
    each target's first ground-truth pose (``needs_gt_init``)."""

    root: str
    targets: str
    width: int
    height: int
    needs_gt: bool
    gt_masks: bool
    timeout: float | None
    fail_fast: bool
    gt_init: bool = False


@dataclass(frozen=True)
class _Shard:
    """One unit of work: the selected images of one scene, in frame order; ``index`` is its place in the run."""

    index: int
    refs: tuple[ImageRef, ...]


@dataclass
class _ShardResult:
    """What one shard gives back: its valid estimates, their non-unit scales by position in ``results``, its
    failure rows, the estimator's wall time per image (s) and the count of images that failed as a whole."""

    index: int
    results: list[ResultRow] = field(default_factory=list)
    scales: dict[int, float] = field(default_factory=dict)
    failures: list[dict[str, Any]] = field(default_factory=list)
    times: list[float] = field(default_factory=list)
    failed_images: int = 0


#: The estimator, objects and settings of the run this process is working for (set by :func:`_init_worker`,
#: or by the driver when the shards run in its own process).
_WORKER: dict[str, Any] = {}


def _scene_shards(refs: Sequence[ImageRef]) -> list[_Shard]:
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


def _init_worker(estimator: Any, options: dict[str, Any] | None, setup: _WorkerSetup) -> None:
    """Load the estimator and the dataset's objects once per worker process."""
    objects = load_dataset_objects(Path(setup.root))
    _WORKER.clear()
    _WORKER.update(est=load_estimator(estimator, **(options or {})), objects=objects, known=set(objects.ids),
                   setup=setup)


def _run_shard(shard: _Shard) -> _ShardResult:
    """Run the worker's estimator on the images of one shard (see :func:`_estimate_image`)."""
    est, objects, known, s = _WORKER["est"], _WORKER["objects"], _WORKER["known"], _WORKER["setup"]
    out = _ShardResult(shard.index)
    reset_estimator(est)  # a shard is one scene: a new sequence
    initialised: set[int] = set()
    for frame, ref in enumerate(shard.refs):
        obs, _ = _observation(ref, objects, s.targets, s.width, s.height, s.needs_gt, s.gt_masks, frame,
                              initialised if s.gt_init else None)
        first, scales = len(out.results), {}
        dt, failed = _estimate_image(est, obs, ref, known, s.timeout, out.results, scales, out.failures,
                                     s.fail_fast)
        out.scales.update({i: scales[id(r)] for i, r in enumerate(out.results[first:], first) if id(r) in scales})
        out.times.append(dt)
        out.failed_images += failed
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
        if sep and module and _is_file_target(module):
            return f"{Path(module).expanduser().resolve()}:{attr}"
        return spec
    try:
        pickle.dumps(spec)
    except Exception as exc:  # noqa: BLE001 - any pickling failure means the same thing
        raise ConfigError(f"estimator {spec!r} cannot be sent to worker processes ({type(exc).__name__}: {exc}); "
                          "give it by name, 'module:attr' or 'path/to/file.py:attr', or use one worker") from exc
    return spec


def _run_shards(est: Any, spec: Any, options: dict[str, Any] | None, shards: list[_Shard], backend: Backend,
                stats: RunStats, progress: bool, setup: _WorkerSetup, objects: Any
                ) -> tuple[list[ResultRow], dict[int, float], list[dict[str, Any]], list[float], int]:
    """Run every shard on ``backend`` (in this process with the loaded ``est`` when the back end says so) and
    join their outputs in shard order, which is the image order of a sequential run.

    Returns:
        ``(results, scales by id(row), failures, times per image in s, images failed as a whole)``.
    """
    from tqdm import tqdm

    in_process = backend.in_process(len(shards))
    init_args = () if in_process else (_portable(spec), options, setup)
    if not in_process:  # a Ray worker may run in another folder
        shards = [_Shard(s.index, tuple(_absolute(r) for r in s.refs)) for s in shards]
    done: dict[int, _ShardResult] = {}
    bar = tqdm(total=sum(len(s.refs) for s in shards), desc="eval", unit="img", disable=not progress,
               dynamic_ncols=True)
    if in_process:
        _WORKER.clear()
        _WORKER.update(est=est, objects=objects, known=set(objects.ids), setup=setup)
    try:
        for res in run_units(_run_shard, shards, backend, init=_init_worker, init_args=init_args, stats=stats):
            done[res.index] = res
            bar.update(len(res.times))
            if progress:
                times = [t for r in done.values() for t in r.times]
                bar.set_postfix(fail=sum(len(r.failures) for r in done.values()),
                                s_per_img=f"{np.mean(times):.3f}")
    finally:
        bar.close()
        if in_process:
            _WORKER.clear()
    results: list[ResultRow] = []
    scales: dict[int, float] = {}
    failures: list[dict[str, Any]] = []
    times: list[float] = []
    for r in (done[i] for i in range(len(shards))):
        scales.update({id(row): r.scales[i] for i, row in enumerate(r.results) if i in r.scales})
        results += r.results
        failures += r.failures
        times += r.times
    return results, scales, failures, times, sum(r.failed_images for r in done.values())


def _per_category(objects, rows: list[dict[str, Any]], per_object: dict[int, dict[str, Any]]
                  ) -> dict[str, dict[str, Any]]:
    """Metrics per object category when the dataset's objects have categories (else ``{}``)."""
    categories = {e.obj_id: e.category for e in objects.entries}
    return aggregate_by_category(rows, per_object, categories) if has_categories(categories) else {}


def _check_out(out_dir: str | Path | None, dataset_dir: Path, overwrite: bool) -> None:
    if out_dir is not None:
        prepare_out_dir(out_dir, overwrite=overwrite, protect=[dataset_dir])


def _describe(spec: Any, est: Any) -> str:
    return spec if isinstance(spec, str) else type(est).__name__


def score_results(results_csv: str | Path, dataset_dir: str | Path, *, split: str = "train_pbr",
                  scenes: Sequence[int] | None = None, max_images: int | None = None, vsd: bool = True,
                  progress: bool = True, out_dir: str | Path | None = None, overwrite: bool = False,
                  labels: str | Path | None = None, tracking: bool | None = None) -> EvalReport:
    """Score a BOP results CSV (from any estimator) against a dataset, as :func:`evaluate` scores its own.

    Every target of the selected images counts (images without rows are misses), so select the same images
    (``scenes``, ``max_images``) as the run that wrote the file.

    Args:
        results_csv: BOP results file (``scene_id,im_id,obj_id,score,R,t,time``; t in mm).
        dataset_dir: BOP dataset root.
        split, scenes, max_images, vsd, progress: As in :func:`evaluate`.
        out_dir: Write ``metrics.json``, ``errors.csv``, ``failures.csv`` (rows referring to unknown images
            or objects) and ``metrics.md``.
        overwrite, labels, tracking: As in :func:`evaluate`.

    Returns:
        The :class:`EvalReport` (``failures`` lists rows for images or objects not in the selection).
    """
    root = Path(dataset_dir)
    _check_out(out_dir, root, overwrite)
    rows = read_bop_results(results_csv)
    objects = load_dataset_objects(root)
    refs = select_images(root, split, scenes, max_images, objects.ids, labels)
    selected = {(r.scene_id, r.im_id) for r in refs}
    known = set(objects.ids)
    failures = []
    for r in rows:
        if r.obj_id not in known:
            failures.append({"scene_id": r.scene_id, "im_id": r.im_id, "obj_id": r.obj_id, "kind": "unknown-object",
                             "message": f"obj_id {r.obj_id} not in the dataset's models {sorted(known)}"})
    overall, per_object, err_rows, names = score_estimates(root, rows, objects=objects, vsd_enabled=vsd,
                                                           progress=progress, _refs=refs)
    used = [r for r in rows if (r.scene_id, r.im_id) in selected]
    img_times: dict[tuple[int, int], float] = {}
    for r in used:
        img_times.setdefault((r.scene_id, r.im_id), r.time)
    t = [v for v in img_times.values() if v >= 0]
    overall["num_images"] = len(refs)
    overall["num_estimates"] = len(used)
    overall["num_failures"] = len(failures)
    overall["num_image_exceptions"] = 0
    overall["mean_time_per_image_s"] = float(np.mean(t)) if t else float("nan")
    overall["median_time_per_image_s"] = float(np.median(t)) if t else float("nan")
    settings = {"dataset": str(root), "split": split, "results": str(results_csv),
                "scenes": None if scenes is None else [int(s) for s in scenes], "max_images": max_images,
                "vsd": bool(vsd), "labels": None if labels is None else str(labels)}
    report = EvalReport(overall=overall, per_object=per_object, errors=err_rows, failures=failures, estimates=used,
                        object_names=names, num_images=len(refs), settings=settings,
                        per_category=_per_category(objects, err_rows, per_object))
    if tracking or (tracking is None and is_sequence_dataset(root)):
        report.tracking = score_tracking(root, used, refs, objects, label=str(results_csv))
    if out_dir is not None:
        _write_outputs(report, Path(out_dir), write_results=False)
    return report


# ---------------------------------------------------------------------------------------------------------
# Output files
_ERROR_COLUMNS = ["scene_id", "im_id", "gt_id", "obj_id", "visib_fract", "diameter_m", "symmetric", "matched",
                  "score", "add", "adi", "add_s_or_add", "re", "re_sym", "te", "mssd", "mspd", "vsd", "scale"]
_FAILURE_COLUMNS = ["scene_id", "im_id", "obj_id", "kind", "message", "exception_type", "traceback"]


def _write_outputs(report: EvalReport, out: Path, write_results: bool) -> None:
    out.mkdir(parents=True, exist_ok=True)
    paths = {}
    if write_results:
        paths["results"] = write_bop_results(out / "results.csv", report.estimates)
    paths["metrics"] = out / "metrics.json"
    paths["errors"] = out / "errors.csv"
    paths["failures"] = out / "failures.csv"
    paths["table"] = out / "metrics.md"
    report.paths = paths
    atomic_write_text(paths["metrics"], json.dumps(report.to_json(), indent=2) + "\n")
    atomic_write_text(paths["errors"], csv_text(report.errors, _ERROR_COLUMNS))
    atomic_write_text(paths["failures"], csv_text(report.failures, _FAILURE_COLUMNS))
    atomic_write_text(paths["table"], format_table(report))
    if report.tracking is not None:
        report.paths.update(write_tracking(report.tracking, out))
