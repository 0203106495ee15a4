"""BOP19 evaluation: pose matching, recall at the BOP19 thresholds, and the Average Recall (AR).

Follows the BOP toolkit (``scripts/eval_calc_errors.py``, ``scripts/eval_calc_scores.py``,
``bop_toolkit_lib/pose_matching.py``) with everything in metres inside:

* Targets are the ground-truth instances with ``visib_fract >= visib_gt_min`` (BOP: 0.1); others are
  neither counted nor matchable.
* Per image and object id, the estimates are sorted by decreasing score and the top ``n_top`` kept
  (BOP19: ``n_top = -1``, as many as there are targets of that object in the image). Errors of an
  estimate are computed against every target of the same ``obj_id`` in the image (the toolkit also
  computes them against the non-target instances, which can never be matched; the result is the same).
* Greedy matching, separately for each error type and threshold: in order of decreasing score, an estimate
  is matched to the not yet matched target with the lowest error among those with ``error < threshold``.
  Each target is matched at most once, each estimate at most once.
* Recall = matched targets / targets. Thresholds (BOP19):
  VSD: ``delta = 0.015 m``, ``tau in {0.05, ..., 0.50}`` x diameter, correct if ``e_vsd(tau) < theta`` for
  ``theta in {0.05, ..., 0.50}`` (a 10 x 10 grid); MSSD: ``e < theta x diameter``,
  ``theta in {0.05, ..., 0.50}``; MSPD: ``e x 640 / image_width < theta`` pixels, ``theta in {5, ..., 50}``.
  ``AR_X`` is the mean recall over X's thresholds and ``AR = mean(AR_VSD, AR_MSSD, AR_MSPD)``.
* As in the toolkit, VSD is 1 for every tau, without rendering, when the projections of the object's
  bounding spheres at the two poses cannot overlap.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from simtest.errors import ConfigError
from simtest.metrics.pose import MSPD_REFERENCE_WIDTH, as_symmetries, mspd, mssd, vsd_from_depth
from simtest.render.zbuffer import render_depth

__all__ = [
    "ResultRow",
    "GroundTruthPose",
    "EvalImage",
    "Bop19Result",
    "VSD_DELTA",
    "VSD_TAUS",
    "VSD_THETAS",
    "MSSD_THETAS",
    "MSPD_THETAS",
    "VISIB_GT_MIN",
    "match_greedy",
    "evaluate_bop19",
]

#: VSD visibility tolerance, metres (BOP19: 15 mm).
VSD_DELTA = 0.015
#: VSD misalignment tolerances, fractions of the object diameter.
VSD_TAUS: tuple[float, ...] = tuple(np.round(np.arange(0.05, 0.51, 0.05), 2).tolist())
#: VSD correctness thresholds (the error is a fraction in [0, 1]).
VSD_THETAS: tuple[float, ...] = VSD_TAUS
#: MSSD correctness thresholds, fractions of the object diameter.
MSSD_THETAS: tuple[float, ...] = VSD_TAUS
#: MSPD correctness thresholds, pixels of a 640 px wide image.
MSPD_THETAS: tuple[float, ...] = tuple(float(x) for x in range(5, 51, 5))
#: Minimum visible fraction of a ground-truth instance to be a target.
VISIB_GT_MIN = 0.1


def _R(R: Any, what: str) -> np.ndarray:
    R = np.asarray(R, dtype=np.float64)
    if R.size != 9:
        raise ConfigError(f"{what}: R must have 9 values (3x3 row-major), got shape {R.shape}")
    R = R.reshape(3, 3).copy()
    R.setflags(write=False)
    return R


def _t(t: Any, what: str) -> np.ndarray:
    t = np.asarray(t, dtype=np.float64).reshape(-1).copy()
    if t.shape != (3,):
        raise ConfigError(f"{what}: t must have 3 values (metres), got {t.size}")
    t.setflags(write=False)
    return t


@dataclass(frozen=True, eq=False)
class ResultRow:
    """One scored pose estimate: a row of a BOP results file, in metres (what an estimator returned for one
    image, with the image's ids; the estimator-side type is :class:`simtest.estimators.PoseEstimate`).

    Attributes:
        scene_id: Scene id.
        im_id: Image id within the scene.
        obj_id: Object id.
        score: Confidence (higher is better).
        R: 3x3 rotation, model -> camera.
        t: Translation (3,), metres, model -> camera.
        time: Seconds spent on the image (-1 if unknown).
    """

    scene_id: int
    im_id: int
    obj_id: int
    score: float
    R: np.ndarray
    t: np.ndarray
    time: float = -1.0

    def __post_init__(self) -> None:
        what = f"estimate (scene {self.scene_id}, im {self.im_id}, obj {self.obj_id})"
        object.__setattr__(self, "R", _R(self.R, what))
        object.__setattr__(self, "t", _t(self.t, what))
        if not np.isfinite(self.score):
            raise ConfigError(f"{what}: score must be finite, got {self.score!r}")


@dataclass(frozen=True, eq=False)
class GroundTruthPose:
    """One annotated object instance (BOP ``scene_gt`` + ``scene_gt_info`` entry, metres).

    Attributes:
        scene_id: Scene id.
        im_id: Image id within the scene.
        gt_id: Index of the instance in the image's ``scene_gt`` list.
        obj_id: Object id.
        R: 3x3 rotation, model -> camera.
        t: Translation (3,), metres.
        visib_fract: Visible fraction of the silhouette in [0, 1].
    """

    scene_id: int
    im_id: int
    gt_id: int
    obj_id: int
    R: np.ndarray
    t: np.ndarray
    visib_fract: float = 1.0

    def __post_init__(self) -> None:
        what = f"ground truth (scene {self.scene_id}, im {self.im_id}, gt {self.gt_id})"
        object.__setattr__(self, "R", _R(self.R, what))
        object.__setattr__(self, "t", _t(self.t, what))


@dataclass(frozen=True, eq=False)
class EvalImage:
    """What the errors need from one test image.

    Attributes:
        K: 3x3 intrinsics (pixels).
        width: Image width (pixels); scales MSPD by ``640 / width``.
        height: Image height (pixels).
        depth: Test depth image (height, width), metres, 0 = no measurement; required for VSD.
    """

    K: np.ndarray
    width: int
    height: int
    depth: np.ndarray | None = None

    def __post_init__(self) -> None:
        K = np.asarray(self.K, dtype=np.float64).reshape(3, 3)
        object.__setattr__(self, "K", K)
        if self.depth is not None and np.shape(self.depth) != (self.height, self.width):
            raise ConfigError(f"test depth has shape {np.shape(self.depth)}, expected "
                              f"({self.height}, {self.width})")


@dataclass(frozen=True)
class Bop19Result:
    """BOP19 scores. Recalls are fractions of the targets.

    Attributes:
        ar: mean(ar_vsd, ar_mssd, ar_mspd) over the error types evaluated.
        ar_vsd: Mean of ``recall_vsd`` (NaN if VSD was not evaluated).
        ar_mssd: Mean of ``recall_mssd``.
        ar_mspd: Mean of ``recall_mspd``.
        recall_vsd: Recall per (tau, theta), shape (len(VSD_TAUS), len(VSD_THETAS)).
        recall_mssd: Recall per MSSD theta.
        recall_mspd: Recall per MSPD theta.
        num_targets: Ground-truth instances with ``visib_fract >= visib_gt_min``.
        num_estimates: Estimates considered (after the per-image top-``n_top`` selection).
        per_object: ``{obj_id: {"ar_vsd", "ar_mssd", "ar_mspd", "ar", "num_targets"}}``.
    """

    ar: float
    ar_vsd: float
    ar_mssd: float
    ar_mspd: float
    recall_vsd: np.ndarray
    recall_mssd: np.ndarray
    recall_mspd: np.ndarray
    num_targets: int
    num_estimates: int
    per_object: dict[int, dict[str, float]] = field(default_factory=dict)


def match_greedy(scores: Sequence[float], errors: np.ndarray, threshold: float,
                 gt_valid: Sequence[bool] | None = None) -> list[tuple[int, int]]:
    """BOP greedy matching of estimates to ground truths for one error threshold.

    In order of decreasing score (stable for ties), each estimate is matched to the unmatched valid ground
    truth with the lowest error among those with ``error < threshold``.

    Args:
        scores: Confidence per estimate (n_est,).
        errors: Errors (n_est, n_gt), in the unit of ``threshold``.
        threshold: Correctness threshold (strict: ``error < threshold``).
        gt_valid: Which ground truths may be matched (default all).

    Returns:
        ``[(est_index, gt_index), ...]`` in matching order.
    """
    errors = np.asarray(errors, dtype=np.float64)
    n_est = len(scores)
    if errors.ndim != 2 or errors.shape[0] != n_est:
        raise ConfigError(f"errors must have shape (n_est={n_est}, n_gt), got {errors.shape}")
    available = np.ones(errors.shape[1], dtype=bool) if gt_valid is None else np.array(gt_valid, dtype=bool)
    order = np.argsort(-np.asarray(scores, dtype=np.float64), kind="stable")
    matches = []
    for i in order:
        e = np.where(available & (errors[i] < threshold), errors[i], np.inf)
        if not np.any(np.isfinite(e)):
            continue
        j = int(np.argmin(e))
        available[j] = False
        matches.append((int(i), j))
    return matches


def _model_parts(model: Any, obj_id: int):
    try:
        vertices = np.asarray(model.vertices, dtype=np.float64)
        faces = np.asarray(model.faces)
        diameter = float(model.diameter)
    except AttributeError as exc:
        raise ConfigError(f"model of obj_id {obj_id} needs .vertices (metres), .faces and .diameter (metres): "
                          f"{exc}") from None
    if hasattr(model, "symmetry_transforms"):
        syms = as_symmetries(model.symmetry_transforms())
    else:
        syms = as_symmetries(getattr(model, "symmetries", None))
    return vertices, faces, diameter, syms


def _spheres_overlap(radius: float, t1: np.ndarray, t2: np.ndarray) -> bool:
    """BOP ``misc.overlapping_sphere_projections`` (normalised image coordinates, a tight bound)."""
    if t1[2] <= 0 or t2[2] <= 0:
        return True
    d = np.linalg.norm(t1[:2] / t1[2] - t2[:2] / t2[2])
    return bool(d < radius * (1.0 / t1[2] + 1.0 / t2[2]))


def evaluate_bop19(estimates: Iterable[ResultRow], ground_truth: Iterable[GroundTruthPose],
                   models: Mapping[int, Any], images: Mapping[tuple[int, int], EvalImage], *,
                   visib_gt_min: float = VISIB_GT_MIN, n_top: int = -1,
                   error_types: Sequence[str] = ("vsd", "mssd", "mspd"), vsd_delta: float = VSD_DELTA,
                   vsd_taus: Sequence[float] = VSD_TAUS, vsd_thetas: Sequence[float] = VSD_THETAS,
                   mssd_thetas: Sequence[float] = MSSD_THETAS, mspd_thetas: Sequence[float] = MSPD_THETAS
                   ) -> Bop19Result:
    """BOP19 Average Recall of pose estimates (see the module doc for the protocol).

    Args:
        estimates: Pose estimates (metres).
        ground_truth: Ground-truth instances of every evaluated image (metres), with ``visib_fract``.
        models: ``obj_id -> model`` with ``.vertices`` (N, 3) metres, ``.faces``, ``.diameter`` (metres) and
            ``.symmetry_transforms()`` -> (S, 4, 4) (e.g. :class:`simtest.objects.ObjectModel`).
        images: ``(scene_id, im_id) -> EvalImage`` (intrinsics, size; depth in metres for VSD).
        visib_gt_min: Minimum ``visib_fract`` of a target (BOP: 0.1); 0 evaluates every instance.
        n_top: Estimates kept per image and object: -1 = the number of targets of that object in the
            image (BOP19), 0 = all, k > 0 = the top k.
        error_types: Any of ``"vsd"``, ``"mssd"``, ``"mspd"``; AR averages those evaluated.
        vsd_delta: VSD visibility tolerance, metres.
        vsd_taus: VSD misalignment tolerances, fractions of the diameter.
        vsd_thetas: VSD correctness thresholds (fractions).
        mssd_thetas: MSSD thresholds, fractions of the diameter.
        mspd_thetas: MSPD thresholds, pixels at 640 px image width.

    Returns:
        :class:`Bop19Result`.

    Raises:
        ConfigError: Unknown error type, no targets, or an image / model missing for a target.
    """
    error_types = tuple(error_types)
    bad = [e for e in error_types if e not in ("vsd", "mssd", "mspd")]
    if bad or not error_types:
        raise ConfigError(f"error_types must be a non-empty subset of ('vsd', 'mssd', 'mspd'), got {error_types!r}")
    if n_top < -1:
        raise ConfigError(f"n_top must be -1, 0 or positive, got {n_top!r}")
    thresholds = {"vsd": (np.asarray(vsd_taus, dtype=np.float64), np.asarray(vsd_thetas, dtype=np.float64)),
                  "mssd": np.asarray(mssd_thetas, dtype=np.float64), "mspd": np.asarray(mspd_thetas, dtype=np.float64)}
    targets, by_group = _group_targets(ground_truth, estimates, visib_gt_min)
    num_targets = sum(len(v) for v in targets.values())

    # Matched-target counts per threshold, per object.
    obj_ids = sorted({k[2] for k in targets})
    taus, thetas = thresholds["vsd"]
    hits = {"vsd": {o: np.zeros((len(taus), len(thetas))) for o in obj_ids},
            "mssd": {o: np.zeros(len(thresholds["mssd"])) for o in obj_ids},
            "mspd": {o: np.zeros(len(thresholds["mspd"])) for o in obj_ids}}
    n_obj_targets = {o: 0 for o in obj_ids}
    parts_cache: dict[int, tuple] = {}
    gt_render_cache: dict[tuple[int, int, int], np.ndarray] = {}
    num_considered = 0

    for key, gts in targets.items():
        scene_id, im_id, obj_id = key
        n_obj_targets[obj_id] += len(gts)
        ests = sorted(by_group.get(key, []), key=lambda e: -float(e.score))
        keep = len(gts) if n_top == -1 else (len(ests) if n_top == 0 else n_top)
        ests = ests[:keep]
        if not ests:
            continue
        num_considered += len(ests)
        if obj_id not in models:
            raise ConfigError(f"no model for obj_id {obj_id}; models given for {sorted(models)}")
        if obj_id not in parts_cache:
            parts_cache[obj_id] = _model_parts(models[obj_id], obj_id)
        image = images.get((scene_id, im_id))
        if image is None:
            raise ConfigError(f"no EvalImage for scene {scene_id}, image {im_id}")
        _count_hits(hits, obj_id, ests, gts, parts_cache[obj_id], image, (scene_id, im_id), error_types,
                    thresholds, vsd_delta, gt_render_cache)

    rec_vsd, ar_vsd = _ar(hits["vsd"], obj_ids, n_obj_targets, "vsd" in error_types)
    rec_mssd, ar_mssd = _ar(hits["mssd"], obj_ids, n_obj_targets, "mssd" in error_types)
    rec_mspd, ar_mspd = _ar(hits["mspd"], obj_ids, n_obj_targets, "mspd" in error_types)
    ar = float(np.nanmean([ar_vsd, ar_mssd, ar_mspd]))
    per_object = {}
    for o in obj_ids:
        vals = {k: _ar(hits[k], [o], n_obj_targets, k in error_types)[1] for k in ("vsd", "mssd", "mspd")}
        per_object[o] = {"ar_vsd": vals["vsd"], "ar_mssd": vals["mssd"], "ar_mspd": vals["mspd"],
                         "ar": float(np.nanmean(list(vals.values()))), "num_targets": n_obj_targets[o]}
    return Bop19Result(ar=ar, ar_vsd=ar_vsd, ar_mssd=ar_mssd, ar_mspd=ar_mspd, recall_vsd=rec_vsd,
                       recall_mssd=rec_mssd, recall_mspd=rec_mspd, num_targets=num_targets,
                       num_estimates=num_considered, per_object=per_object)


def _group_targets(ground_truth: Iterable[GroundTruthPose], estimates: Iterable[ResultRow],
                   visib_gt_min: float) -> tuple[dict, dict]:
    """Targets (``visib_fract >= visib_gt_min``) and the estimates of their groups, keyed by
    ``(scene_id, im_id, obj_id)``.

    Raises:
        ConfigError: No target at all.
    """
    targets: dict[tuple[int, int, int], list[GroundTruthPose]] = defaultdict(list)
    for g in ground_truth:
        if g.visib_fract >= visib_gt_min:
            targets[(int(g.scene_id), int(g.im_id), int(g.obj_id))].append(g)
    if not targets:
        raise ConfigError(f"no ground-truth instance has visib_fract >= {visib_gt_min!r}; nothing to evaluate")
    by_group: dict[tuple[int, int, int], list[ResultRow]] = defaultdict(list)
    for e in estimates:
        key = (int(e.scene_id), int(e.im_id), int(e.obj_id))
        if key in targets:
            by_group[key].append(e)
    return targets, by_group


def _count_hits(hits: dict, obj_id: int, ests: list, gts: list, parts: tuple, image: EvalImage,
                image_key: tuple[int, int], error_types: tuple[str, ...], thresholds: dict, vsd_delta: float,
                gt_render_cache: dict) -> None:
    """Add the matched-target counts of one (image, object) group at every threshold to ``hits``."""
    vertices, faces, diameter, syms = parts
    scores = [float(e.score) for e in ests]
    if "mssd" in error_types:
        E = np.array([[mssd(e.R, e.t, g.R, g.t, vertices, syms) for g in gts] for e in ests])
        for k, th in enumerate(thresholds["mssd"]):
            hits["mssd"][obj_id][k] += len(match_greedy(scores, E, th * diameter))
    if "mspd" in error_types:
        E = np.array([[mspd(e.R, e.t, g.R, g.t, image.K, vertices, syms) for g in gts] for e in ests])
        E *= MSPD_REFERENCE_WIDTH / float(image.width)
        for k, th in enumerate(thresholds["mspd"]):
            hits["mspd"][obj_id][k] += len(match_greedy(scores, E, th))
    if "vsd" in error_types:
        taus, thetas = thresholds["vsd"]
        E = _vsd_errors(ests, gts, parts, image, image_key, taus, vsd_delta, gt_render_cache)
        for a in range(len(taus)):
            for b, th in enumerate(thetas):
                hits["vsd"][obj_id][a, b] += len(match_greedy(scores, E[:, :, a], th))


def _vsd_errors(ests: list, gts: list, parts: tuple, image: EvalImage, image_key: tuple[int, int],
                taus: np.ndarray, vsd_delta: float, gt_render_cache: dict) -> np.ndarray:
    """VSD errors (n_est, n_gt, n_taus); pairs whose bounding spheres do not overlap keep error 1."""
    vertices, faces, diameter, _ = parts
    scene_id, im_id = image_key
    if image.depth is None:
        raise ConfigError(f"VSD needs the test depth of scene {scene_id}, image {im_id}")
    E = np.ones((len(ests), len(gts), len(taus)))
    radius = 0.5 * diameter
    for i, e in enumerate(ests):
        depth_est = None
        for j, g in enumerate(gts):
            if not _spheres_overlap(radius, e.t, g.t):
                continue
            if depth_est is None:
                depth_est = render_depth(vertices, faces, e.R, e.t, image.K, image.width, image.height)
            gkey = (scene_id, im_id, g.gt_id)
            if gkey not in gt_render_cache:
                gt_render_cache[gkey] = render_depth(vertices, faces, g.R, g.t, image.K, image.width, image.height)
            E[i, j] = vsd_from_depth(depth_est, gt_render_cache[gkey], image.depth, image.K, vsd_delta, taus,
                                     diameter)
    return E


def _ar(hits: dict[int, np.ndarray], objs: Iterable[int], n_obj_targets: dict[int, int],
        evaluated: bool) -> tuple[np.ndarray, float]:
    """(recall per threshold, average recall) pooled over ``objs``; NaN when the error type was not evaluated."""
    if not evaluated:
        shape = next(iter(hits.values())).shape
        return np.full(shape, np.nan), float("nan")
    objs = list(objs)
    total = sum(hits[o] for o in objs) / float(sum(n_obj_targets[o] for o in objs))
    return total, float(np.mean(total))
