"""Run a pose estimator over a BOP dataset and score it; or score an existing BOP results CSV.

:func:`evaluate` iterates the images of a split, builds one :class:`~simtest.estimators.base.Observation` per
image, calls the estimator (timing it, catching every exception: a failing image is recorded and the run goes
on), rejects invalid estimates (NaN / inf, not a rotation, unknown object id), writes the estimates as a BOP
results CSV and scores them with :func:`score_estimates`. :func:`score_results` scores a results CSV written
by any estimator, with the same code, so both give the same numbers.

Scoring protocol
----------------
* **Targets** are the ground-truth instances with ``visib_fract >= 0.1`` (BOP19's ``visib_gt_min``). With
  ``targets="gt-masks"`` the estimator is told these instances (object ids, visible masks, visible boxes).
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

Outputs (``out_dir``): ``results.csv`` (BOP format, t in mm), ``metrics.json``, ``errors.csv`` (one row per
target), ``failures.csv`` (image, object, kind, message) and ``metrics.md`` (Markdown tables, units in the
column headers).
"""

from __future__ import annotations

import json
import logging
import math
import time
import traceback
from collections import defaultdict
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from simtest.errors import ConfigError, DatasetError
from simtest.estimators.base import Estimator, Observation, load_estimator
from simtest.estimators.base import PoseEstimate as EstimatorPose
from simtest.io import bop
from simtest.io.bop_results import read_bop_results, write_bop_results
from simtest.io.files import atomic_write_text, csv_text, jsonable, prepare_out_dir
from simtest.metrics.auc import ADDS_2CM, YCB_AUC_MAX_THRESHOLD, ycb_auc
from simtest.metrics.bop19 import VISIB_GT_MIN, VSD_DELTA, VSD_TAUS, EvalImage, GroundTruthPose, evaluate_bop19
from simtest.metrics.bop19 import PoseEstimate as ResultRow
from simtest.metrics.pose import MSPD_REFERENCE_WIDTH, add, adi, mspd, mssd, re, te, vsd

__all__ = ["EvalReport", "evaluate", "score_results", "score_estimates", "load_dataset_objects", "TARGET_MODES",
           "NDEG_MCM"]

log = logging.getLogger(__name__)

#: How targets are given to the estimator.
TARGET_MODES = ("gt-masks", "none")
#: (degrees, centimetres) pairs of the n deg m cm accuracies.
NDEG_MCM: tuple[tuple[float, float], ...] = ((5, 2), (5, 5), (10, 2), (10, 5))
_ROT_TOL = 1e-3


# ---------------------------------------------------------------------------------------------------------
# Dataset access
def load_dataset_objects(dataset_dir: str | Path):
    """The object set the dataset's poses refer to: ``DATASET/models/`` if present, else the manifest's
    ``object_set`` (a built-in name or a path).

    Raises:
        DatasetError: Neither exists.
    """
    root = Path(dataset_dir)
    models_dir = root / "models"
    if (models_dir / "models_info.json").is_file():
        from simtest.io.bop_models import read_bop_models

        return read_bop_models(models_dir)
    manifest = root / "manifest.json"
    if manifest.is_file():
        name = json.loads(manifest.read_text()).get("object_set")
        if name:
            from simtest.objects import load_object_set

            return load_object_set(name)
    raise DatasetError(f"{root}: no models/models_info.json and no 'object_set' in manifest.json; cannot tell "
                       "which object models the poses refer to")


@dataclass(frozen=True)
class _ImageRef:
    scene_id: int
    im_id: int
    scene_dir: Path
    info: dict  # read_scene entry: K, depth_scale, gt


def _iter_images(dataset_dir: Path, split: str, scenes: Sequence[int] | None,
                 max_images: int | None) -> list[_ImageRef]:
    split_dir = dataset_dir / split
    if not split_dir.is_dir():
        have = sorted(p.name for p in dataset_dir.iterdir() if p.is_dir()) if dataset_dir.is_dir() else []
        raise DatasetError(f"{split_dir}: split folder not found (dataset folders: {', '.join(have) or 'none'})")
    if max_images is not None and int(max_images) < 1:
        raise ConfigError(f"max_images must be >= 1 or None, got {max_images!r}")
    dirs = bop.scene_dirs(split_dir)
    if scenes is not None:
        want = {int(s) for s in scenes}
        known = {int(d.name) for d in dirs}
        missing = sorted(want - known)
        if missing:
            raise ConfigError(f"scenes {missing} not in {split_dir}; available: {sorted(known)}")
        dirs = [d for d in dirs if int(d.name) in want]
    refs: list[_ImageRef] = []
    for d in dirs:
        frames = bop.read_scene(d)
        for im_id in sorted(frames):
            refs.append(_ImageRef(int(d.name), im_id, d, frames[im_id]))
            if max_images is not None and len(refs) >= int(max_images):
                return refs
    if not refs:
        raise DatasetError(f"{split_dir}: no images found")
    return refs


def _image_size(dataset_dir: Path, ref: _ImageRef) -> tuple[int, int]:
    cam = bop.read_camera_json(dataset_dir / "camera.json")
    return int(cam["width"]), int(cam["height"])


def _targets(ref: _ImageRef, objects) -> list[tuple[int, bop.ImageGT]]:
    """(gt_id, gt) of the instances that are scored: visib_fract >= VISIB_GT_MIN and a known model."""
    known = set(objects.ids)
    return [(j, g) for j, g in enumerate(ref.info["gt"]) if g.visib_fract >= VISIB_GT_MIN and g.obj_id in known]


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
        failures: One dict per failure (``failures.csv`` rows): ``scene_id, im_id, obj_id, kind, message``.
        estimates: The valid estimates, as BOP result rows (metres).
        object_names: ``{obj_id: name}``.
        num_images: Images evaluated.
        paths: Files written (``results``, ``metrics``, ``errors``, ``failures``, ``table``).
        settings: What was evaluated (dataset, split, estimator, targets, vsd).
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

    def table(self) -> str:
        """Markdown tables (per object and overall), ready to paste."""
        return format_table(self)

    def to_json(self) -> dict[str, Any]:
        return {"settings": self.settings, "num_images": self.num_images, "overall": jsonable(self.overall),
                "per_object": {str(k): {"name": self.object_names.get(k, str(k)), **jsonable(v)}
                               for k, v in sorted(self.per_object.items())},
                "num_failures": len(self.failures),
                "definitions": METRIC_DEFINITIONS}


METRIC_DEFINITIONS = {
    "targets": f"ground-truth instances with visib_fract >= {VISIB_GT_MIN}; a target without a matched "
               "estimate is a miss (distance inf, rotation error pi)",
    "matching": "per image and object, estimates by decreasing score take the unassigned target with the "
                "nearest translation",
    "add_s_or_add_01d": "fraction of targets with ADD(-S) < 0.1 x diameter (ADD-S for symmetric objects)",
    "auc_adds / auc_add_s_or_add": f"YCB-Video VOC-style AUC of ADD-S / ADD(-S), thresholds 0 to "
                                   f"{YCB_AUC_MAX_THRESHOLD} m",
    "adds_lt_2cm": f"fraction of targets with ADD-S < {ADDS_2CM} m",
    "acc_pi_6 / acc_pi_18 / median_re_deg": "viewpoint protocol on re_sym (smallest geodesic error over the "
                                            "symmetry set), misses = pi",
    "NdegMcm": "fraction with re_sym <= N degrees and te <= M cm",
    "ar*": "BOP19 Average Recall (VSD delta 15 mm, taus/thetas 0.05..0.5, MSSD 0.05..0.5 x diameter, MSPD 5..50 "
           "px at 640 px width); ar = mean of the evaluated ones",
    "units": "distances in metres (keys ending _m), angles in degrees (_deg), time in seconds (_s)",
}


# ---------------------------------------------------------------------------------------------------------
# Scoring
def _re_sym(R_e: np.ndarray, R_g: np.ndarray, syms: np.ndarray) -> float:
    """Smallest geodesic angle (degrees) between ``R_e`` and ``R_g R_s`` over the symmetry rotations."""
    M = R_g.T @ R_e  # trace(R_e (R_g R_s)^T) = sum(M * R_s)
    tr = np.einsum("ij,sij->s", M, syms[:, :3, :3])
    return float(np.degrees(np.arccos(np.clip(0.5 * (tr.max() - 1.0), -1.0, 1.0))))


def _match(ests: list[ResultRow], targets: list[tuple[int, bop.ImageGT]]) -> dict[int, int]:
    """{target index -> estimate index}: by decreasing score, nearest translation, one estimate per target."""
    order = sorted(range(len(ests)), key=lambda i: -float(ests[i].score))
    free = set(range(len(targets)))
    out: dict[int, int] = {}
    for i in order:
        cands = [j for j in free if targets[j][1].obj_id == ests[i].obj_id]
        if not cands:
            continue
        j = min(cands, key=lambda j: float(np.linalg.norm(ests[i].t - targets[j][1].T_cam_obj.t)))
        free.discard(j)
        out[j] = i
    return out


def _aggregate(rows: list[dict[str, Any]]) -> dict[str, Any]:
    n = len(rows)
    inf = float("inf")

    def col(key: str, miss: float) -> np.ndarray:
        return np.array([r[key] if r["matched"] else miss for r in rows], dtype=np.float64)

    adds = col("adi", inf)
    addsa = col("add_s_or_add", inf)
    diam = np.array([r["diameter_m"] for r in rows])
    re_s = col("re_sym", 180.0)
    te_m = col("te", inf)
    out: dict[str, Any] = {
        "num_targets": n,
        "num_matched": int(sum(r["matched"] for r in rows)),
        "add_s_or_add_01d": float(np.mean(addsa < 0.1 * diam)),
        "auc_adds": ycb_auc(adds),
        "auc_add_s_or_add": ycb_auc(addsa),
        "adds_lt_2cm": float(np.mean(adds < ADDS_2CM)),
        "acc_pi_6": float(np.mean(np.radians(re_s) < np.pi / 6)),
        "acc_pi_18": float(np.mean(np.radians(re_s) < np.pi / 18)),
        "median_re_deg": float(np.median(re_s)),
        "median_te_m": float(np.median(te_m)),
        "mean_add_s_or_add_m": float(np.mean(addsa[np.isfinite(addsa)])) if np.isfinite(addsa).any() else inf,
    }
    for nd, mc in NDEG_MCM:
        out[f"{nd:g}deg{mc:g}cm"] = float(np.mean((re_s <= nd) & (te_m <= mc / 100.0)))
    return out


def score_estimates(dataset_dir: str | Path, estimates: Iterable[ResultRow], *, split: str = "train_pbr",
                    scenes: Sequence[int] | None = None, max_images: int | None = None, vsd_enabled: bool = True,
                    scales: dict[int, float] | None = None, objects=None, progress: bool = False,
                    _refs: list | None = None) -> tuple[dict, dict, list[dict], dict[int, str]]:
    """Score estimates (metres) against the dataset's ground truth.

    Args:
        dataset_dir: BOP dataset root.
        estimates: Result rows (:class:`simtest.metrics.bop19.PoseEstimate`, metres).
        split: Split folder name.
        scenes: Scene ids to evaluate (default all).
        max_images: Evaluate only the first N images (scenes in order, images in order).
        vsd_enabled: Compute VSD (per-target mean over taus and BOP19 AR_VSD).
        scales: Optional ``{id(estimate): scale}`` to copy into the error rows.
        objects: The object set (default :func:`load_dataset_objects`).
        progress: Show a progress bar.

    Returns:
        ``(overall, per_object, error_rows, object_names)``; every target of the selected images counts,
        images without estimates are all misses.
    """
    from tqdm import tqdm

    root = Path(dataset_dir)
    objects = load_dataset_objects(root) if objects is None else objects
    refs = _refs if _refs is not None else _iter_images(root, split, scenes, max_images)
    width, height = _image_size(root, refs[0])
    by_image: dict[tuple[int, int], list[ResultRow]] = defaultdict(list)
    for e in estimates:
        by_image[(int(e.scene_id), int(e.im_id))].append(e)
    models = {o.obj_id: o for o in objects}
    sym_cache: dict[int, np.ndarray] = {}
    rows: list[dict[str, Any]] = []
    # BOP19 hit counts: sum over images of ar_x * num_targets, per object.
    bop_hits: dict[int, dict[str, float]] = defaultdict(lambda: defaultdict(float))
    error_types = ("vsd", "mssd", "mspd") if vsd_enabled else ("mssd", "mspd")
    for ref in tqdm(refs, desc="score", unit="img", disable=not progress, dynamic_ncols=True):
        targets = _targets(ref, objects)
        if not targets:
            continue
        ests = [e for e in by_image.get((ref.scene_id, ref.im_id), []) if e.obj_id in models]
        K = ref.info["K"]
        depth = bop.read_depth(ref.scene_dir, ref.im_id, ref.info["depth_scale"]) if vsd_enabled else None
        match = _match(ests, targets)
        for j, (gt_id, g) in enumerate(targets):
            obj = models[g.obj_id]
            if g.obj_id not in sym_cache:
                sym_cache[g.obj_id] = obj.symmetry_transforms()
            syms = sym_cache[g.obj_id]
            R_g, t_g = g.T_cam_obj.R, g.T_cam_obj.t
            row: dict[str, Any] = {"scene_id": ref.scene_id, "im_id": ref.im_id, "gt_id": gt_id, "obj_id": g.obj_id,
                                   "visib_fract": float(g.visib_fract), "diameter_m": float(obj.diameter),
                                   "symmetric": bool(obj.is_symmetric), "matched": j in match}
            if j in match:
                e = ests[match[j]]
                pts = obj.vertices
                row.update(score=float(e.score), add=add(e.R, e.t, R_g, t_g, pts), adi=adi(e.R, e.t, R_g, t_g, pts))
                row["add_s_or_add"] = row["adi"] if obj.is_symmetric else row["add"]
                row.update(re=re(e.R, R_g), re_sym=_re_sym(e.R, R_g, syms), te=te(e.t, t_g),
                           mssd=mssd(e.R, e.t, R_g, t_g, pts, syms),
                           mspd=mspd(e.R, e.t, R_g, t_g, K, pts, syms) * MSPD_REFERENCE_WIDTH / width)
                if vsd_enabled:
                    row["vsd"] = float(np.mean(vsd(e.R, e.t, R_g, t_g, depth, K, obj, VSD_DELTA, VSD_TAUS,
                                                   obj.diameter)))
                if scales is not None and id(e) in scales:
                    row["scale"] = float(scales[id(e)])
            rows.append(row)
        # BOP19 on this image.
        gts = [GroundTruthPose(ref.scene_id, ref.im_id, j, g.obj_id, g.T_cam_obj.R, g.T_cam_obj.t, g.visib_fract)
               for j, g in enumerate(ref.info["gt"]) if g.obj_id in models]
        res = evaluate_bop19(ests, gts, models, {(ref.scene_id, ref.im_id): EvalImage(K, width, height, depth)},
                             error_types=error_types)
        for o, po in res.per_object.items():
            n = po["num_targets"]
            for k in ("ar_vsd", "ar_mssd", "ar_mspd"):
                if math.isfinite(po[k]):
                    bop_hits[o][k] += po[k] * n
            bop_hits[o]["n"] += n
    if not rows:
        raise DatasetError(f"{root}/{split}: no ground-truth instance with visib_fract >= {VISIB_GT_MIN} and a "
                           "known model in the selected images; nothing to score")

    def bop_of(objs: Iterable[int]) -> dict[str, float]:
        objs = list(objs)
        n = sum(bop_hits[o]["n"] for o in objs)
        out = {}
        for k in ("ar_vsd", "ar_mssd", "ar_mspd"):
            out[k] = sum(bop_hits[o][k] for o in objs) / n if (n and (k != "ar_vsd" or vsd_enabled)) else float("nan")
        vals = [out[k] for k in ("ar_vsd", "ar_mssd", "ar_mspd") if math.isfinite(out[k])]
        out["ar"] = float(np.mean(vals)) if vals else float("nan")
        return out

    overall = _aggregate(rows)
    overall.update(bop_of(bop_hits))
    per_object: dict[int, dict[str, Any]] = {}
    by_obj: dict[int, list] = defaultdict(list)
    for r in rows:
        by_obj[r["obj_id"]].append(r)
    for o in sorted(by_obj):
        per_object[o] = _aggregate(by_obj[o])
        per_object[o].update(bop_of([o]))
    names = {o.obj_id: o.name for o in objects}
    return overall, per_object, rows, names


# ---------------------------------------------------------------------------------------------------------
# Running an estimator
def _observation(ref: _ImageRef, objects, targets: str, width: int, height: int,
                 needs_gt: bool) -> tuple[Observation, list[tuple[int, bop.ImageGT]]]:
    rgb = bop.read_image(ref.scene_dir, ref.im_id)
    depth = bop.read_depth(ref.scene_dir, ref.im_id, ref.info["depth_scale"])
    tg = _targets(ref, objects)
    kw: dict[str, Any] = {}
    if targets == "gt-masks":
        kw["target_obj_ids"] = tuple(g.obj_id for _, g in tg)
        kw["masks"] = tuple(bop.read_mask(ref.scene_dir, ref.im_id, j, visible=True) for j, _ in tg)
        kw["boxes"] = tuple(tuple(int(v) for v in g.bbox_visib) for _, g in tg)
        if needs_gt:
            kw["gt_poses"] = tuple((g.T_cam_obj.R.copy(), g.T_cam_obj.t.copy()) for _, g in tg)
    obs = Observation(rgb=rgb, depth=depth, K=ref.info["K"].copy(), width=width, height=height, objects=objects,
                      scene_id=ref.scene_id, im_id=ref.im_id, **kw)
    return obs, tg


def _check_estimate(e: Any, known: set[int]) -> str | None:
    """Why an estimate is invalid, or None."""
    if not isinstance(e, EstimatorPose):
        return f"expected simtest.estimators.PoseEstimate, got {type(e).__name__}"
    try:
        R = np.asarray(e.R, dtype=np.float64)
        t = np.asarray(e.t, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        return f"R / t are not numeric: {exc}"
    if R.shape != (3, 3) or t.reshape(-1).shape != (3,):
        return f"R must be 3x3 and t a 3-vector (metres), got shapes {R.shape} and {t.shape}"
    if not (np.all(np.isfinite(R)) and np.all(np.isfinite(t)) and np.isfinite(float(e.score))):
        return "non-finite estimate (NaN or inf in R, t or score)"
    if not np.isfinite(float(e.scale)):
        return f"non-finite scale {e.scale!r}"
    dev = float(np.abs(R @ R.T - np.eye(3)).max())
    if dev > _ROT_TOL or np.linalg.det(R) < 0:
        return f"R is not a rotation matrix (max |R R^T - I| = {dev:.2g}, det = {np.linalg.det(R):.3f})"
    if int(e.obj_id) not in known:
        return f"unknown obj_id {e.obj_id!r}; dataset objects: {sorted(known)}"
    return None


def _failure(ref: _ImageRef, obj_id: Any, kind: str, message: str) -> dict[str, Any]:
    return {"scene_id": ref.scene_id, "im_id": ref.im_id, "obj_id": "" if obj_id is None else obj_id,
            "kind": kind, "message": message}


def evaluate(dataset_dir: str | Path, estimator: str | Estimator | Any, *, split: str = "train_pbr",
             targets: str = "gt-masks", scenes: Sequence[int] | None = None, max_images: int | None = None,
             progress: bool = True, out_dir: str | Path | None = None, vsd: bool = True,
             estimator_options: dict[str, Any] | None = None, overwrite: bool = False) -> EvalReport:
    """Run ``estimator`` on every selected image of a BOP dataset and score it.

    Args:
        dataset_dir: BOP dataset root (with ``models/`` or a manifest naming the object set).
        estimator: A name (``oracle``, ``icp``, ``umeyama``), ``"module:attr"``, an instance with
            ``estimate(observation)`` or a callable; see :func:`simtest.estimators.load_estimator`.
        split: Split folder (``train_pbr``).
        targets: ``"gt-masks"``: tell the estimator the targets (object ids, visible masks and boxes);
            ``"none"``: the estimator finds objects itself. Ground-truth poses are passed only to estimators
            with ``needs_gt = True`` (the ``oracle``), and only with ``"gt-masks"``.
        scenes: Scene ids to evaluate (default all).
        max_images: Evaluate only the first N images.
        progress: Show a tqdm progress bar.
        out_dir: Write ``results.csv``, ``metrics.json``, ``errors.csv``, ``failures.csv``, ``metrics.md``.
        vsd: Also compute VSD (per-target errors and AR_VSD); about 5-10 ms per estimate at 320x240.
        estimator_options: Options for a named estimator (ignored for instances).
        overwrite: Allow a non-empty ``out_dir`` (its files of these names are replaced); checked before the
            estimator is loaded. ``out_dir`` may never be, or lie inside, ``dataset_dir``.

    Returns:
        The :class:`EvalReport`.

    Raises:
        ConfigError: Unknown ``targets`` value or estimator, or an estimator needing ground truth with
            ``targets="none"``.
        DatasetError: Missing split, scenes or models; ``out_dir`` not empty without ``overwrite``, not
            writable, or inside ``dataset_dir``.

    An exception raised by the estimator on an image is recorded in ``failures.csv`` (its targets count as
    misses) and the run goes on. An estimator may also expose ``last_failures``: a list of
    ``{"obj_id", "reason"}`` dicts describing the targets it gave up on in its last call; they are recorded
    with kind ``no-estimate``.
    """
    from tqdm import tqdm

    if targets not in TARGET_MODES:
        raise ConfigError(f"targets must be one of {', '.join(TARGET_MODES)}, got {targets!r}")
    root = Path(dataset_dir)
    _check_out(out_dir, root, overwrite)
    est = load_estimator(estimator, **(estimator_options or {}))
    needs_gt = bool(getattr(est, "needs_gt", False))
    if needs_gt and targets == "none":
        raise ConfigError(f"estimator {estimator!r} needs ground-truth targets (needs_gt = True); use "
                          "targets='gt-masks'")
    objects = load_dataset_objects(root)
    known = set(objects.ids)
    refs = _iter_images(root, split, scenes, max_images)
    width, height = _image_size(root, refs[0])
    results: list[ResultRow] = []
    scales: dict[int, float] = {}
    failures: list[dict[str, Any]] = []
    times: list[float] = []
    bar = tqdm(refs, desc="eval", unit="img", disable=not progress, dynamic_ncols=True)
    for ref in bar:
        obs, _ = _observation(ref, objects, targets, width, height, needs_gt)
        t0 = time.perf_counter()
        try:
            out = est.estimate(obs)
            out = list(out) if out is not None else []
        except Exception as exc:  # noqa: BLE001 - every estimator error is recorded, never fatal
            dt = time.perf_counter() - t0
            times.append(dt)
            msg = f"{type(exc).__name__}: {exc}"
            log.warning("estimator failed on scene %d image %d: %s\n%s", ref.scene_id, ref.im_id, msg,
                        traceback.format_exc())
            failures.append(_failure(ref, None, "exception", msg))
            continue
        dt = time.perf_counter() - t0
        times.append(dt)
        for f in list(getattr(est, "last_failures", None) or []):
            failures.append(_failure(ref, f.get("obj_id"), "no-estimate", str(f.get("reason", ""))))
        for e in out:
            why = _check_estimate(e, known)
            if why is not None:
                failures.append(_failure(ref, getattr(e, "obj_id", None), "invalid-estimate", why))
                continue
            row = ResultRow(scene_id=ref.scene_id, im_id=ref.im_id, obj_id=int(e.obj_id), score=float(e.score),
                            R=np.asarray(e.R, dtype=np.float64), t=np.asarray(e.t, dtype=np.float64).reshape(3),
                            time=dt)
            results.append(row)
            if float(e.scale) != 1.0:
                scales[id(row)] = float(e.scale)
        if progress:
            bar.set_postfix(fail=len(failures), s_per_img=f"{np.mean(times):.3f}")
    overall, per_object, rows, names = score_estimates(root, results, objects=objects, vsd_enabled=vsd,
                                                       scales=scales, progress=False, _refs=refs)
    overall["num_images"] = len(refs)
    overall["num_estimates"] = len(results)
    overall["num_failures"] = len(failures)
    overall["num_image_exceptions"] = sum(f["kind"] == "exception" for f in failures)
    overall["mean_time_per_image_s"] = float(np.mean(times)) if times else float("nan")
    overall["median_time_per_image_s"] = float(np.median(times)) if times else float("nan")
    settings = {"dataset": str(root), "split": split, "estimator": _describe(estimator, est), "targets": targets,
                "scenes": None if scenes is None else [int(s) for s in scenes], "max_images": max_images,
                "vsd": bool(vsd), "estimator_options": jsonable(estimator_options or {})}
    report = EvalReport(overall=overall, per_object=per_object, errors=rows, failures=failures, estimates=results,
                        object_names=names, num_images=len(refs), settings=settings)
    if out_dir is not None:
        _write_outputs(report, Path(out_dir), write_results=True)
    return report


def _check_out(out_dir: str | Path | None, dataset_dir: Path, overwrite: bool) -> None:
    if out_dir is not None:
        prepare_out_dir(out_dir, overwrite=overwrite, protect=[dataset_dir])


def _describe(spec: Any, est: Any) -> str:
    return spec if isinstance(spec, str) else type(est).__name__


def score_results(results_csv: str | Path, dataset_dir: str | Path, *, split: str = "train_pbr",
                  scenes: Sequence[int] | None = None, max_images: int | None = None, vsd: bool = True,
                  progress: bool = True, out_dir: str | Path | None = None, overwrite: bool = False) -> EvalReport:
    """Score a BOP results CSV (from any estimator) against a dataset, as :func:`evaluate` scores its own.

    Every target of the selected images counts (images without rows are misses), so select the same images
    (``scenes``, ``max_images``) as the run that wrote the file.

    Args:
        results_csv: BOP results file (``scene_id,im_id,obj_id,score,R,t,time``; t in mm).
        dataset_dir: BOP dataset root.
        split, scenes, max_images, vsd, progress: As in :func:`evaluate`.
        out_dir: Write ``metrics.json``, ``errors.csv``, ``failures.csv`` (rows referring to unknown images
            or objects) and ``metrics.md``.
        overwrite: As in :func:`evaluate`.

    Returns:
        The :class:`EvalReport` (``failures`` lists rows for images or objects not in the selection).
    """
    root = Path(dataset_dir)
    _check_out(out_dir, root, overwrite)
    rows = read_bop_results(results_csv)
    objects = load_dataset_objects(root)
    refs = _iter_images(root, split, scenes, max_images)
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
                "vsd": bool(vsd)}
    report = EvalReport(overall=overall, per_object=per_object, errors=err_rows, failures=failures, estimates=used,
                        object_names=names, num_images=len(refs), settings=settings)
    if out_dir is not None:
        _write_outputs(report, Path(out_dir), write_results=False)
    return report


# ---------------------------------------------------------------------------------------------------------
# Output files
_ERROR_COLUMNS = ["scene_id", "im_id", "gt_id", "obj_id", "visib_fract", "diameter_m", "symmetric", "matched",
                  "score", "add", "adi", "add_s_or_add", "re", "re_sym", "te", "mssd", "mspd", "vsd", "scale"]
_FAILURE_COLUMNS = ["scene_id", "im_id", "obj_id", "kind", "message"]


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


def _pct(v: float) -> str:
    return "–" if not math.isfinite(v) else f"{100.0 * v:.1f}"


def _num(v: float, scale: float = 1.0, digits: int = 1) -> str:
    return "inf" if v == float("inf") else ("–" if not math.isfinite(v) else f"{v * scale:.{digits}f}")


def format_table(report: EvalReport) -> str:
    """Markdown tables: per object and overall; units in the headers (percent, degrees, centimetres)."""
    vsd_on = bool(report.settings.get("vsd", True))
    ar_label = "AR [%]" if vsd_on else "AR (MSSD, MSPD) [%]"
    cols = ["Object", "N", "ADD(-S)-0.1d [%]", "AUC ADD-S [%]", "AUC ADD(-S) [%]", "ADD-S<2cm [%]",
            "Acc@π/6 [%]", "Acc@π/18 [%]", "MedErr [deg]", "Med te [cm]", "5°5cm [%]", "10°5cm [%]",
            ar_label] + (["AR_VSD [%]"] if vsd_on else []) + ["AR_MSSD [%]", "AR_MSPD [%]"]

    def line(name: str, m: dict[str, Any]) -> str:
        cells = [name, str(m["num_targets"]), _pct(m["add_s_or_add_01d"]), _pct(m["auc_adds"]),
                 _pct(m["auc_add_s_or_add"]), _pct(m["adds_lt_2cm"]), _pct(m["acc_pi_6"]), _pct(m["acc_pi_18"]),
                 _num(m["median_re_deg"]), _num(m["median_te_m"], 100.0, 2), _pct(m["5deg5cm"]),
                 _pct(m["10deg5cm"]), _pct(m["ar"])] + ([_pct(m["ar_vsd"])] if vsd_on else []) + [
                 _pct(m["ar_mssd"]), _pct(m["ar_mspd"])]
        return "| " + " | ".join(cells) + " |"

    head = "| " + " | ".join(cols) + " |\n|" + "|".join(["---"] + ["---:"] * (len(cols) - 1)) + "|\n"
    body = [line(f"{report.object_names.get(o, o)} ({o})", m) for o, m in sorted(report.per_object.items())]
    body.append(line("**All**", report.overall))
    s = report.settings
    o = report.overall
    title = s.get("estimator") or s.get("results", "")
    footer = (f"\n{report.num_images} images, {o['num_targets']} targets (visib_fract >= {VISIB_GT_MIN}), "
              f"{o.get('num_estimates', 0)} estimates, {o.get('num_failures', 0)} failures; "
              f"time per image: mean {_num(o.get('mean_time_per_image_s', float('nan')), 1.0, 3)} s.\n"
              "ADD(-S): ADD-S for symmetric objects. AUC: YCB-Video VOC-style, 0-10 cm. Rotation errors are the "
              "smallest over the object's symmetries; misses count as 180°. AR: BOP19 Average Recall.\n")
    return f"### {title} on {Path(s.get('dataset', '')).name} / {s.get('split', '')}\n\n" + head + "\n".join(
        body) + "\n" + footer


def overall_table(report: EvalReport) -> str:
    """A short plain-text summary of the overall scores (for terminals)."""
    o = report.overall
    items = [("ADD(-S)-0.1d", _pct(o["add_s_or_add_01d"]) + " %"), ("AUC ADD-S", _pct(o["auc_adds"]) + " %"),
             ("AUC ADD(-S)", _pct(o["auc_add_s_or_add"]) + " %"), ("ADD-S<2cm", _pct(o["adds_lt_2cm"]) + " %"),
             ("Acc@pi/6", _pct(o["acc_pi_6"]) + " %"), ("Acc@pi/18", _pct(o["acc_pi_18"]) + " %"),
             ("median re", _num(o["median_re_deg"], 1.0, 2) + " deg"),
             ("median te", _num(o["median_te_m"], 100.0, 2) + " cm")]
    items += [(k, _pct(o[k]) + " %") for k in (f"{n:g}deg{m:g}cm" for n, m in NDEG_MCM)]
    items += [("AR", _pct(o["ar"]) + " %"), ("AR_VSD", _pct(o["ar_vsd"]) + " %"),
              ("AR_MSSD", _pct(o["ar_mssd"]) + " %"), ("AR_MSPD", _pct(o["ar_mspd"]) + " %"),
              ("targets", str(o["num_targets"])), ("estimates", str(o.get("num_estimates", ""))),
              ("failures", str(o.get("num_failures", ""))),
              ("time/image", _num(o.get("mean_time_per_image_s", float("nan")), 1.0, 4) + " s")]
    w = max(len(k) for k, _ in items)
    return "\n".join(f"{k:<{w}}  {v}" for k, v in items)
