"""Run a pose estimator over a BOP dataset and score it; or score an existing BOP results CSV.

:func:`evaluate` iterates the images of a split, builds one :class:`~simtest.estimators.base.Observation` per
image, calls the estimator through :func:`simtest.estimators.guard.call_estimator` (timing it, with a per-image
time limit; an exception, ``sys.exit``, a timeout or a return value that is not a list is recorded and the run
goes on), rejects invalid estimates (:func:`~simtest.estimators.guard.check_estimate`: not PoseEstimate-like,
wrong shapes, NaN / inf, not a rotation, unknown object id), writes the estimates as a BOP results CSV and
scores them with :func:`score_estimates`. The estimator's optional ``prepare(objects)`` runs once per worker
before its first image, outside the limit (caches, template banks); an estimator may declare a longer limit
(``time_limit_s``, :func:`simtest.estimators.guard.resolve_timeout`). :func:`score_results` scores a results
CSV written by any estimator, with the same code, so both give the same numbers.

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
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from simtest.backend import Backend, RunStats, preflight
from simtest.errors import ConfigError, DatasetError
from simtest.estimators.base import (GT_INIT_LABEL, GT_MASKS_LABEL, Estimator, gt_access, needs_depth,
                                     needs_gt_init)
from simtest.estimators.registry import load_estimator
from simtest.estimators.guard import AUTO_TIMEOUT, resolve_timeout
from simtest.evaluation.detection import keep_top_per_image, score_detection
from simtest.evaluation.images import WorkerSetup, run_scene_shards, scene_shards, targets_needed
from simtest.evaluation.tracking import TrackingReport, is_sequence_dataset, score_tracking, write_tracking
from simtest.io.bop_results import read_bop_results, write_bop_results
from simtest.io.bop import resolve_split
from simtest.io.dataset import DataNotes, image_size, select_images
from simtest.io.files import atomic_write_text, csv_text, jsonable, prepare_out_dir
from simtest.metrics.bop19 import ResultRow
from simtest.metrics.registry import NDEG_MCM, definitions
from simtest.metrics.tolerance import read_tolerance_map
from simtest.objects.loaders import load_dataset_objects
from simtest.evaluation.scoring import aggregate_by_category, has_categories, score_estimates
from simtest.evaluation.tables import failure_counts, format_table, overall_table

log = logging.getLogger(__name__)

__all__ = ["EvalReport", "evaluate", "score_results", "score_estimates", "load_dataset_objects", "TARGET_MODES",
           "TASKS", "NDEG_MCM", "format_table", "overall_table", "failure_counts"]


#: How targets are given to the estimator.
TARGET_MODES = ("gt-masks", "none")
#: What the estimator is asked: BOP19 localization (told the objects and their counts) or BOP24 detection.
TASKS = ("localization", "detection")


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
            objects fall into categories (:func:`simtest.evaluation.scoring.has_categories`), else empty.
        tracking: The tracking scores of a sequence evaluation (:mod:`simtest.evaluation.tracking`), else ``None``.
        classification: In the detection task, one row per target of the class-agnostic matching
            (:func:`simtest.evaluation.detection.classification_rows`; ``classification.csv``), else empty.
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
    classification: list[dict[str, Any]] = field(default_factory=list)

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
                "definitions": definitions(self.settings.get("task", "localization"))}


#: Definitions written into ``metrics.json`` (from :mod:`simtest.metrics.registry`).
METRIC_DEFINITIONS = definitions()


# ---------------------------------------------------------------------------------------------------------
# Running an estimator
def evaluate(dataset_dir: str | Path, estimator: str | Estimator | Any, *, split: str | None = None,
             targets: str = "gt-masks", scenes: Sequence[int] | None = None, max_images: int | None = None,
             progress: bool = True, out_dir: str | Path | None = None, vsd: bool = True,
             estimator_options: dict[str, Any] | None = None,
             timeout: float | str | None = AUTO_TIMEOUT, overwrite: bool = False,
             fail_fast: bool = False, labels: str | Path | None = None, tracking: bool | None = None,
             backend: Backend | None = None, stats: RunStats | None = None,
             task: str = "localization", grasp_tolerance: str | Path | None = None) -> EvalReport:
    """Run ``estimator`` on every selected image of a BOP dataset and score it.

    Args:
        dataset_dir: BOP dataset root (with ``models/`` or a manifest naming the object set).
        estimator: A name (``oracle``, ``icp``, ``umeyama``), ``"module:attr"``, an instance with
            ``estimate(observation)`` or a callable; see :func:`simtest.estimators.load_estimator`.
        split: Split folder (``train_pbr``, ``test``); None: the dataset's only split.
        targets: ``"gt-masks"``: tell the estimator the targets' object ids, and their ground-truth visible
            masks and boxes if it declares ``needs_gt_masks`` (the run is then labelled ``NAME (GT masks)``);
            ``"none"``: nothing, the estimator finds objects itself (one that cannot, e.g. ``icp``, fails).
            Ground-truth poses are passed only to estimators with ``needs_gt = True`` (the ``oracle``), and
            only with ``"gt-masks"``.
        scenes: Scene ids to evaluate (default all).
        max_images: Evaluate only the first N images.
        progress: Show a tqdm progress bar.
        out_dir: Write ``results.csv``, ``metrics.json``, ``errors.csv``, ``failures.csv``, ``metrics.md``.
        vsd: Also compute VSD (per-target errors and AR_VSD); about 5-10 ms per estimate at 320x240. Skipped,
            with a note in ``metrics.md``, when the dataset has no depth.
        estimator_options: Options for a named estimator (ignored for instances).
        timeout: Time limit of one ``estimate()`` call, seconds (``None``/0: none; ``"auto"``: 120 or the
            estimator's longer ``time_limit_s``); an image over it is a ``timeout`` failure, the run goes on.
        overwrite: Allow a non-empty ``out_dir`` (its files of these names are replaced); checked before the
            estimator is loaded. ``out_dir`` may never be, or lie inside, ``dataset_dir``.
        fail_fast: Stop at the first fault of the estimator (any failure kind but ``no-estimate``) by raising
            :class:`~simtest.errors.EstimatorError` with its traceback; nothing is written.
        labels: Folder of withheld labels (``<labels>/<split>/<scene>/scene_gt.json`` and masks) for a split
            without them; default ``<dataset>/withheld`` when the manifest says ``"unlabelled": true``
            (:func:`simtest.io.dataset.labels_root`). Images and depth come from the split either way.
        tracking: Also score the run as tracking (:mod:`simtest.evaluation.tracking`: per-frame 3D IoU, n deg m cm,
            errors over time, frames tracked before loss; ``tracking.md``, ``tracking.csv``, ``tracking.png``
            in ``out_dir``). ``None``: when the dataset's manifest says ``rig = "sequence"``.
        backend: Where the images run (default: this process). Every worker loads the estimator and the
            objects once; a unit of work is one scene, its images in frame order (see :func:`scene_shards`).
            The outputs are the same for every back end and worker count but for the measured times.
        stats: Filled with the units finished, retried and failed (:class:`simtest.backend.RunStats`).
        task: ``"localization"`` (BOP19: the estimator is told the targets as ``targets`` says) or
            ``"detection"`` (BOP24: it is told nothing, ``targets`` is ignored; an estimator that needs the
            targets is refused; scored by :mod:`simtest.evaluation.detection` as well).
        grasp_tolerance: A ``tolerance.csv`` of ``simtest tolerance`` (see :func:`score_results`).

    Returns:
        The :class:`EvalReport`.

    Raises:
        ConfigError: Unknown ``targets`` value or estimator, an estimator needing ground truth with
            ``targets="none"``, or a negative ``timeout``.
        EstimatorError: With ``fail_fast``, the estimator's first fault.
        DatasetError: Missing dataset folder, split or models, or malformed ground truth (an unknown
            ``obj_id``, a non-finite or non-rotation pose, missing scene files); checked before the estimator
            runs. ``out_dir`` not empty without ``overwrite``, not writable, or inside ``dataset_dir``. No
            ``depth/`` for an estimator that reads depth, no ``mask_visib/`` for one given masks.
            Real BOP test sets are read as distributed (:func:`simtest.io.dataset.select_images`).

    Estimator faults never end the run: an image where the estimator raises (kind ``exception``), calls
    ``sys.exit`` (``exit``), exceeds ``timeout`` (``timeout``) or returns something other than a list
    (``invalid-return``) is recorded in ``failures.csv`` and its targets count as misses; an invalid element of
    the returned list is recorded as ``invalid-estimate`` and dropped. ``KeyboardInterrupt`` stops the run. An
    estimator may also expose ``last_failures``: a list of ``{"obj_id", "reason"}`` dicts describing the
    targets it gave up on in its last call; they are recorded with kind ``no-estimate``.
    """
    if targets not in TARGET_MODES:
        raise ConfigError(f"targets must be one of {', '.join(TARGET_MODES)}, got {targets!r}")
    _check_task(task)
    tolerance = _tolerance_map(grasp_tolerance)  # a bad file fails before the estimator runs
    root = Path(dataset_dir)
    split = resolve_split(root, split)
    preflight(backend or Backend())  # before the output is touched
    _check_out(out_dir, root, overwrite)
    est = load_estimator(estimator, **(estimator_options or {}))
    gt_masks, needs_gt = gt_access(est)
    gt_init = needs_gt_init(est)
    if task == "detection":  # nothing is told about the image: refuse an estimator that needs it
        targets, gt_masks, gt_init = _refuse_targets(estimator, est)
    if (needs_gt or gt_init) and targets == "none" and task != "detection":
        raise ConfigError(f"estimator {estimator!r} needs ground-truth targets (needs_gt or needs_gt_init = True); "
                          "use targets='gt-masks'")
    gt_masks = gt_masks and targets == "gt-masks"
    objects = _objects_for(root, est)
    limit = resolve_timeout(timeout, est)  # after check_objects: a shipped choice may declare its own
    notes = DataNotes()
    refs = select_images(root, split, scenes, max_images, set(objects.ids), labels, notes)
    vsd = _check_inputs(estimator, est, notes, gt_masks, vsd)
    width, height = image_size(root)
    backend, stats = backend or Backend(), stats or RunStats()
    run = run_scene_shards(est, estimator, estimator_options, scene_shards(refs), backend, stats, progress,
                      WorkerSetup(str(root.resolve()), targets, width, height, needs_gt, gt_masks, limit, fail_fast,
                                   gt_init, task),
                      objects)
    results, scales, failures, times, failed_images = run
    if task == "detection":  # the highest-scored 100 per image, as the BOP toolkit reads them
        results, scales = _keep_top(results, scales)
    overall, per_object, rows, names = score_estimates(root, results, objects=objects, vsd_enabled=vsd,
                                                       scales=scales, progress=False, _refs=refs, tolerance=tolerance)
    overall.update(_run_counts(len(refs), len(results), failures, times))
    labelled = gt_masks and not needs_gt  # the oracle's name says it
    settings = {"dataset": str(root), "split": split,
                "estimator": _describe(estimator, est) + (GT_MASKS_LABEL if labelled else "")
                + (GT_INIT_LABEL if gt_init else ""),
                "gt_masks": labelled, "gt_init": gt_init, "targets": targets,
                **_selection_settings(scenes, max_images, vsd, labels, task, notes, grasp_tolerance),
                "estimator_options": jsonable(estimator_options or {}), "timeout_s": limit,
                "backend": backend.name, "workers": backend.workers}
    report = EvalReport(overall=overall, per_object=per_object, errors=rows, failures=failures, estimates=results,
                        object_names=names, num_images=len(refs), settings=settings,
                        num_failed_images=failed_images, per_category=_per_category(objects, rows, per_object))
    if task == "detection":
        _add_detection(report, refs, results, objects, width)
    if tracking or (tracking is None and is_sequence_dataset(root)):
        report.tracking = score_tracking(root, results, refs, objects, label=settings["estimator"])
    if out_dir is not None:
        _write_outputs(report, Path(out_dir), write_results=True)
    return report


def _tolerance_map(path: str | Path | None):
    """The grasp tolerance map of ``path`` (a ``tolerance.csv``), or None."""
    return None if path is None else read_tolerance_map(path)


def _selection_settings(scenes: Sequence[int] | None, max_images: int | None, vsd: bool,
                        labels: str | Path | None, task: str, notes: DataNotes,
                        grasp_tolerance: str | Path | None = None) -> dict[str, Any]:
    """The ``settings`` entries that say which images were scored and how (with the data notes, if any)."""
    return {"scenes": None if scenes is None else [int(s) for s in scenes], "max_images": max_images,
            "vsd": bool(vsd), "labels": None if labels is None else str(labels),
            **({"task": task} if task == "detection" else {}),
            **({"grasp_tolerance": str(grasp_tolerance)} if grasp_tolerance is not None else {}),
            **({"data_notes": notes.summary()} if notes.summary() else {})}


def _objects_for(root: Path, est: Any):
    """The dataset's objects, checked by the estimator when it can (``check_objects``: a network trained for
    other objects is one error before the run, not a failure per image)."""
    objects = load_dataset_objects(root)
    if callable(getattr(est, "check_objects", None)):
        est.check_objects(objects)
    return objects


def _run_counts(num_images: int, num_estimates: int, failures: list[dict[str, Any]], times: list[float]
                ) -> dict[str, Any]:
    """The counts and times of a run that go into ``overall`` (seconds per image)."""
    return {"num_images": num_images, "num_estimates": num_estimates, "num_failures": len(failures),
            "num_image_exceptions": sum(f["kind"] == "exception" for f in failures),
            "mean_time_per_image_s": float(np.mean(times)) if times else float("nan"),
            "median_time_per_image_s": float(np.median(times)) if times else float("nan")}


def _check_inputs(spec: Any, est: Any, notes: DataNotes, gt_masks: bool, vsd: bool) -> bool:
    """Refuse, before anything runs, an estimator that reads what the dataset lacks: depth (``needs_depth``)
    or ground-truth visible masks (``needs_gt_masks`` with targets given). Returns whether VSD is computed
    (:func:`_vsd_possible`)."""
    name = spec if isinstance(spec, str) else type(est).__name__
    if not notes.has_depth and needs_depth(est):
        raise DatasetError(f"the dataset has no depth/ (scenes {notes.no_depth_scenes[:8]}) and estimator {name!r} "
                           "reads depth (needs_depth is not False); use an RGB-only estimator (keypoints, oracle) "
                           "or a copy of the dataset with depth (e.g. BOP's lmo_test_bop19 has depth/)")
    if not notes.has_masks and gt_masks and not getattr(est, "needs_gt", False):
        raise DatasetError(f"the dataset has no mask_visib/ (scenes {notes.no_mask_scenes[:8]}) and estimator {name!r} "
                           "is given ground-truth visible masks (needs_gt_masks = True); use one that finds the "
                           "objects itself")
    return _vsd_possible(vsd, notes)


def _vsd_possible(vsd: bool, notes: DataNotes) -> bool:
    """``vsd``, unless the dataset has no depth: then False, with a note (VSD compares depth maps)."""
    if vsd and not notes.has_depth:
        notes.lines.append("VSD skipped: it needs the test depth images (AR is the mean of AR_MSSD and AR_MSPD)")
        log.info("VSD skipped: the dataset has no depth/")
        return False
    return vsd


def _refuse_targets(spec: Any, est: Any) -> tuple[str, bool, bool]:
    """``(targets, gt_masks, gt_init)`` of a detection run; :class:`ConfigError` when the estimator cannot run
    without being told the targets."""
    why = targets_needed(est)
    if why is not None:
        raise ConfigError(f"estimator {spec if isinstance(spec, str) else type(est).__name__!r} cannot run the "
                          f"detection task, which tells no target ids or counts: {why}")
    return "none", False, False


def _keep_top(results: list[ResultRow], scales: list[float]) -> tuple[list[ResultRow], list[float]]:
    """The rows (and their scales) among the 100 of highest score of their image, in their order."""
    kept = {id(r) for r in keep_top_per_image(results)}
    pairs = [(r, s) for r, s in zip(results, scales, strict=True) if id(r) in kept]
    return [r for r, _ in pairs], [s for _, s in pairs]


def _check_task(task: str) -> None:
    if task not in TASKS:
        raise ConfigError(f"task must be one of {', '.join(TASKS)}, got {task!r}")


def _add_detection(report: EvalReport, refs, results: list[ResultRow], objects, width: int) -> None:
    """Add the detection task's scores (BOP24 AP, classification) to ``report``: into ``overall``,
    ``per_object`` and ``per_category``; the per-target classification rows into ``classification``."""
    categories = {e.obj_id: e.category for e in objects.entries}
    det = score_detection(refs, results, {o.obj_id: o for o in objects}, categories, width,
                          has_categories(categories))
    report.overall.update(det.overall)
    for o, m in det.per_object.items():
        report.per_object.setdefault(o, {}).update(m)
    for c, m in det.per_category.items():
        report.per_category.setdefault(c, {}).update(m)
    report.classification = det.rows


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


def score_results(results_csv: str | Path, dataset_dir: str | Path, *, split: str | None = None,
                  scenes: Sequence[int] | None = None, max_images: int | None = None, vsd: bool = True,
                  progress: bool = True, out_dir: str | Path | None = None, overwrite: bool = False,
                  labels: str | Path | None = None, tracking: bool | None = None,
                  task: str = "localization", grasp_tolerance: str | Path | None = None) -> EvalReport:
    """Score a BOP results CSV (from any estimator) against a dataset, as :func:`evaluate` scores its own.

    Every target of the selected images counts (images without rows are misses), so select the same images
    (``scenes``, ``max_images``) as the run that wrote the file.

    Args:
        results_csv: BOP results file (``scene_id,im_id,obj_id,score,R,t,time``; t in mm).
        dataset_dir: BOP dataset root.
        split, scenes, max_images, vsd, progress: As in :func:`evaluate`.
        out_dir: Write ``metrics.json``, ``errors.csv``, ``failures.csv`` (rows referring to unknown images
            or objects) and ``metrics.md``.
        overwrite, labels, tracking, task: As in :func:`evaluate` (with ``"detection"`` the 100 rows of
            highest score per image are scored, as the BOP toolkit reads the file).
        grasp_tolerance: A ``tolerance.csv`` of ``simtest tolerance``: adds the ``grasp_tolerance`` metric
            (targets whose estimate lies within the object's measured grasp tolerance on every axis) and the
            ``grasp_ready`` column of ``errors.csv``, for the objects the map covers.

    Returns:
        The :class:`EvalReport` (``failures`` lists rows for images or objects not in the selection).
    """
    _check_task(task)
    tolerance = _tolerance_map(grasp_tolerance)
    root = Path(dataset_dir)
    _check_out(out_dir, root, overwrite)
    rows = read_bop_results(results_csv)
    if task == "detection":
        kept = {id(r) for r in keep_top_per_image(rows)}
        rows = [r for r in rows if id(r) in kept]
    objects = load_dataset_objects(root)
    split = resolve_split(root, split)
    notes = DataNotes()
    refs = select_images(root, split, scenes, max_images, objects.ids, labels, notes)
    vsd = _vsd_possible(vsd, notes)
    selected = {(r.scene_id, r.im_id) for r in refs}
    known = set(objects.ids)
    failures = []
    for r in rows:
        if r.obj_id not in known:
            failures.append({"scene_id": r.scene_id, "im_id": r.im_id, "obj_id": r.obj_id, "kind": "unknown-object",
                             "message": f"obj_id {r.obj_id} not in the dataset's models {sorted(known)}"})
    overall, per_object, err_rows, names = score_estimates(root, rows, objects=objects, vsd_enabled=vsd,
                                                           progress=progress, _refs=refs, tolerance=tolerance)
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
                **_selection_settings(scenes, max_images, vsd, labels, task, notes, grasp_tolerance)}
    report = EvalReport(overall=overall, per_object=per_object, errors=err_rows, failures=failures, estimates=used,
                        object_names=names, num_images=len(refs), settings=settings,
                        per_category=_per_category(objects, err_rows, per_object))
    if task == "detection":
        _add_detection(report, refs, used, objects, image_size(root)[0])
    if tracking or (tracking is None and is_sequence_dataset(root)):
        report.tracking = score_tracking(root, used, refs, objects, label=str(results_csv))
    if out_dir is not None:
        _write_outputs(report, Path(out_dir), write_results=False)
    return report


# ---------------------------------------------------------------------------------------------------------
# Output files
_ERROR_COLUMNS = ["scene_id", "im_id", "gt_id", "obj_id", "visib_fract", "diameter_m", "symmetric", "matched",
                  "score", "add", "adi", "add_s_or_add", "re", "re_sym", "te", "mssd", "mspd", "vsd", "scale",
                  "grasp_ready"]
_CLASSIFICATION_COLUMNS = ["scene_id", "im_id", "gt_id", "obj_id", "category", "matched", "est_obj_id",
                           "est_category", "classified", "re_sym"]
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
    if report.settings.get("task") == "detection":
        paths["classification"] = out / "classification.csv"
        atomic_write_text(paths["classification"], csv_text(report.classification, _CLASSIFICATION_COLUMNS))
    if report.tracking is not None:
        report.paths.update(write_tracking(report.tracking, out))
