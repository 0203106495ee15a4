"""Pictures of an evaluation run (``simtest eval --out RUN``): where each estimate lies against the ground truth.

An evaluation folder holds ``metrics.json`` (its ``settings`` name the dataset and split evaluated),
``errors.csv`` (one row per target: ``re`` degrees, ``te``, ``mssd``, ``add_s_or_add`` metres, ``mspd``
pixels, ``matched``), ``results.csv`` (BOP format, t in mm; read in metres) and ``failures.csv``.

On every picture the ground truth is green (visible-mask contour, 3D box) and the estimate magenta (contour of
the projected mesh's silhouette, 3D box), both ``K (R x + t)`` in the OpenCV camera frame. A target counts as
correct when ADD(-S) < 0.1 of the object's diameter (the run's ``add_s_or_add_01d``). Estimates are matched
to targets as the scorer matches them (:func:`simtest.evaluation.scoring.image_matches`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from simtest.errors import ConfigError, DatasetError
from simtest.evaluation.scoring import image_matches
from simtest.io import bop
from simtest.io.bop_results import read_bop_results
from simtest.io.dataset import ImageRef, select_images
from simtest.io.files import read_csv
from simtest.metrics.bop19 import ResultRow
from simtest.viz.dataset_page import ImageSelection, select_show_images
from simtest.viz.draw import (BAD_COLOUR, EST_COLOUR, GT_COLOUR, box_corner_pixels, draw_box, draw_label,
                              draw_mask_contour, mesh_silhouette, to_canvas)
from simtest.viz.sheet import BG, hstack, legend_strip, text_strip, titled, upscale, upscale_factor, vstack

__all__ = ["EVAL_FILES", "is_eval_run", "EvalRun", "load_eval_run", "TargetError", "target_errors",
           "worst_targets", "image_index", "target_card", "image_card", "failure_cards", "eval_images",
           "EVAL_LEGEND",
           "ERROR_COLUMNS"]

#: Files that make a folder an evaluation run.
EVAL_FILES = ("metrics.json", "errors.csv")
#: errors.csv columns ``--worst`` can rank by (larger = worse).
ERROR_COLUMNS = ("mssd", "mspd", "add_s_or_add", "add", "adi", "re", "re_sym", "te", "vsd")
EVAL_LEGEND = [(GT_COLOUR, "ground truth: visible mask, 3D box", "solid"),
               (EST_COLOUR, "estimate: projected mesh silhouette, 3D box", "solid")]


def is_eval_run(path: Path) -> bool:
    """Whether ``path`` is an evaluation folder (it holds :data:`EVAL_FILES`)."""
    return all((Path(path) / n).is_file() for n in EVAL_FILES)


@dataclass(frozen=True)
class TargetError:
    """One row of ``errors.csv``: ids, and the errors (metres, degrees, pixels; inf for a miss)."""

    scene_id: int
    im_id: int
    gt_id: int
    obj_id: int
    visib_fract: float
    diameter_m: float
    matched: bool
    values: dict

    @property
    def correct(self) -> bool:
        """ADD(-S) below 0.1 of the diameter (``add_s_or_add_01d``)."""
        return self.matched and self.values["add_s_or_add"] < 0.1 * self.diameter_m

    def summary(self) -> str:
        """``re 5.1 deg  te 1.2 cm  MSSD 2.3 cm  MSPD 8.1 px  ADD(-S) 1.0 cm < 0.1d (1.2 cm): correct``."""
        v = self.values
        if not self.matched:
            return "no estimate (miss)"
        ok = "correct" if self.correct else "wrong"
        sign = "<" if self.correct else ">="
        return (f"re {v['re']:.1f} deg  te {v['te'] * 100:.1f} cm  MSSD {v['mssd'] * 100:.1f} cm  "
                f"MSPD {v['mspd']:.1f} px  ADD(-S) {v['add_s_or_add'] * 100:.1f} cm {sign} 0.1d "
                f"({self.diameter_m * 10:.1f} cm): {ok}")


def _float(text: str) -> float:
    try:
        return float(text)
    except (TypeError, ValueError):
        return math.nan


@dataclass
class EvalRun:
    """An evaluation folder read back: its dataset, targets, estimates and failures."""

    run_dir: Path
    dataset: Path
    split: str
    estimator: str
    errors: list[TargetError]
    estimates: list[ResultRow]
    failures: list[dict]


def _dataset_of(run_dir: Path, settings: dict, data: str | Path | None) -> Path:
    if data is not None:
        return Path(data)
    name = settings.get("dataset")
    if not name:
        raise DatasetError(f"{run_dir / 'metrics.json'}: settings name no dataset; give it with --data DIR")
    found = _near_run(run_dir, str(name), Path.is_dir)
    if found is not None:
        return found
    raise DatasetError(f"{run_dir / 'metrics.json'}: the evaluated dataset {name!r} is not there any more; "
                       "give it with --data DIR")


def load_eval_run(run_dir: str | Path, data: str | Path | None = None) -> EvalRun:
    """Read an evaluation folder; ``data`` overrides the dataset its ``metrics.json`` names.

    Raises:
        DatasetError: A missing or malformed file, or the dataset is not found.
    """
    run_dir = Path(run_dir)
    metrics = bop.read_json(run_dir / "metrics.json")
    settings = metrics.get("settings", {}) if isinstance(metrics, dict) else {}
    dataset = _dataset_of(run_dir, settings, data)
    rows = []
    for r in read_csv(run_dir / "errors.csv"):
        try:
            rows.append(TargetError(int(r["scene_id"]), int(r["im_id"]), int(r["gt_id"]), int(r["obj_id"]),
                                    _float(r["visib_fract"]), _float(r["diameter_m"]), r["matched"] in ("1", "True"),
                                    {k: _float(r.get(k, "")) for k in ERROR_COLUMNS}))
        except (KeyError, ValueError) as exc:
            raise DatasetError(f"{run_dir / 'errors.csv'}: malformed row ({exc})") from None
    results = _results_of(run_dir, settings)
    estimates = read_bop_results(results) if results is not None else []
    failures = read_csv(run_dir / "failures.csv") if (run_dir / "failures.csv").is_file() else []
    scored = settings.get("results")  # a run that scored a results file is labelled by that file
    label = settings.get("estimator") or (f"results {Path(str(scored)).name}" if scored else "?")
    return EvalRun(run_dir, dataset, str(settings.get("split", "train_pbr")), str(label), rows, estimates, failures)


def _results_of(run_dir: Path, settings: dict) -> Path | None:
    """The run's estimates: its own ``results.csv``, else (a run that scored a results file, ``simtest eval
    --results``) the file its settings name (:func:`_near_run`); None when neither is there (the page then
    draws the ground truth alone)."""
    own = run_dir / "results.csv"
    if own.is_file():
        return own
    name = settings.get("results")
    return _near_run(run_dir, str(name), Path.is_file) if name else None


def _near_run(run_dir: Path, name: str, exists) -> Path | None:
    """A path a run's settings name, as given (from where the run was made), inside the run folder or beside it:
    the first for which ``exists`` holds, else None."""
    for cand in (Path(name), run_dir / name, run_dir.parent / name):
        if exists(cand):
            return cand
    return None


def target_errors(run: EvalRun) -> dict[tuple[int, int, int], TargetError]:
    """``{(scene_id, im_id, gt_id): row}`` of the run's targets."""
    return {(e.scene_id, e.im_id, e.gt_id): e for e in run.errors}


def worst_targets(run: EvalRun, n: int, by: str = "mssd") -> list[TargetError]:
    """The ``n`` targets with the largest ``by`` error (misses first: their errors are infinite).

    Raises:
        ConfigError: ``by`` is not an error column or ``n`` < 1.
    """
    if by not in ERROR_COLUMNS:
        raise ConfigError(f"--by must be one of {', '.join(ERROR_COLUMNS)}, got {by!r}")
    if n < 1:
        raise ConfigError(f"--worst must be >= 1, got {n}")

    def key(e: TargetError) -> float:
        v = e.values[by] if e.matched else math.inf
        return -math.inf if math.isnan(v) else v

    return sorted(run.errors, key=key, reverse=True)[:n]


def _estimate_overlay(canvas, K, est: ResultRow, obj, scale: int, width: int, height: int) -> np.ndarray:
    """Draw an estimate (silhouette contour, box); returns its box corner pixels (8, 2), camera pixels."""
    sil = mesh_silhouette(K, est.R, est.t, obj.vertices, obj.faces, width, height, scale)
    draw_mask_contour(canvas, sil, EST_COLOUR, 1, thickness=2)
    corners = box_corner_pixels(K, est.R, est.t, obj.keypoints_bbox)
    draw_box(canvas, corners, EST_COLOUR, scale)
    return corners


def _gt_overlay(canvas, ref: ImageRef, gt_id: int, obj, scale: int) -> np.ndarray:
    g = ref.info["gt"][gt_id]
    if ref.has_masks:  # real BOP test sets ship none
        try:
            draw_mask_contour(canvas, bop.read_mask(ref.gt_dir, ref.im_id, gt_id, True), GT_COLOUR, scale, 2)
        except DatasetError:
            pass
    corners = box_corner_pixels(ref.info["K"], g.T_cam_obj.R, g.T_cam_obj.t, obj.keypoints_bbox)
    draw_box(canvas, corners, GT_COLOUR, scale)
    return corners


def _zoom(canvas: np.ndarray, pts_canvas: np.ndarray, size: int) -> np.ndarray:
    """A square crop of ``canvas`` around ``pts_canvas`` (with a margin; beyond the image: background),
    resized to ``size`` x ``size``."""
    pts = pts_canvas[np.isfinite(pts_canvas).all(axis=1)]
    H, W = canvas.shape[:2]
    if not len(pts):
        return cv2.resize(canvas, (size, size), interpolation=cv2.INTER_AREA)
    lo, hi = np.clip(pts.min(axis=0), 0, [W - 1, H - 1]), np.clip(pts.max(axis=0), 0, [W - 1, H - 1])
    c, half = (lo + hi) / 2, max(24.0, 0.6 * float(np.max(hi - lo)))
    x0, y0, n = int(c[0] - half), int(c[1] - half), int(2 * half)
    pad = np.full((n, n, 3), BG, dtype=np.uint8)
    sx0, sy0, sx1, sy1 = max(0, x0), max(0, y0), min(W, x0 + n), min(H, y0 + n)
    pad[sy0 - y0:sy1 - y0, sx0 - x0:sx1 - x0] = canvas[sy0:sy1, sx0:sx1]
    return cv2.resize(pad, (size, size), interpolation=cv2.INTER_LINEAR if size > n else cv2.INTER_AREA)


def image_index(run: EvalRun, objects, keys: Sequence[tuple[int, int]], refs: Sequence[ImageRef] | None = None):
    """``{(scene, im): (ref, estimates, match)}`` of the images ``keys``; ``refs``: those images already read
    (:func:`eval_images`), else they are read from the dataset."""
    want = set(keys)
    if refs is None:
        refs = select_images(run.dataset, run.split, sorted({s for s, _ in want}), None, objects.ids)
    refs = [r for r in refs if (r.scene_id, r.im_id) in want]
    models = {o.obj_id: o for o in objects}
    return {(ref.scene_id, ref.im_id): (ref, ests, match)
            for ref, _, ests, match in image_matches(refs, run.estimates, models)}


def target_card(run: EvalRun, objects, target: TargetError, index, scale: int | None = None) -> np.ndarray:
    """One target: the image with its ground truth and matched estimate, a zoom on them, and its errors."""
    ref, ests, match = index[(target.scene_id, target.im_id)]
    rgb = bop.read_image(ref.scene_dir, ref.im_id)
    h, w = rgb.shape[:2]
    s = upscale_factor(w, h) if scale is None else int(scale)
    canvas = upscale(rgb, s)
    obj = objects.get(target.obj_id)
    pts = [to_canvas(_gt_overlay(canvas, ref, target.gt_id, obj, s), s)]
    if target.gt_id in match:
        pts.append(to_canvas(_estimate_overlay(canvas, ref.info["K"], ests[match[target.gt_id]], obj, s, w, h), s))
    zoom = _zoom(canvas, np.vstack(pts), canvas.shape[0])
    col = GT_COLOUR if target.correct else BAD_COLOUR
    head = (f"scene {ref.scene_id} image {ref.im_id}  [gt {target.gt_id}] {obj.name} (obj {obj.obj_id}), "
            f"visib {target.visib_fract:.2f}")
    body = hstack([canvas, zoom])
    return vstack([titled(body, head, [(target.summary(), col)]), legend_strip(EVAL_LEGEND, body.shape[1])], 2)


def image_card(run: EvalRun, objects, key: tuple[int, int], index, scale: int | None = None) -> np.ndarray:
    """One image: every target's ground truth and matched estimate, false positives, a line per target."""
    ref, ests, match = index[key]
    rgb = bop.read_image(ref.scene_dir, ref.im_id)
    h, w = rgb.shape[:2]
    s = upscale_factor(w, h) if scale is None else int(scale)
    canvas = upscale(rgb, s)
    errs = target_errors(run)
    K = ref.info["K"]
    lines: list = []
    placed: list = []
    for j, g in enumerate(ref.info["gt"]):
        te = errs.get((ref.scene_id, ref.im_id, j))
        if te is None:
            continue
        obj = objects.get(g.obj_id)
        corners = _gt_overlay(canvas, ref, j, obj, s)
        if j in match:
            _estimate_overlay(canvas, K, ests[match[j]], obj, s, w, h)
        col = GT_COLOUR if te.correct else BAD_COLOUR
        top = to_canvas(corners, s)
        top = top[np.isfinite(top).all(axis=1)]
        if len(top):
            draw_label(canvas, f"[{j}] {obj.name} {'ok' if te.correct else 'wrong' if te.matched else 'miss'}",
                       (top[:, 0].min(), top[:, 1].min() - 20), colour=col, avoid=placed)
        lines.append((f"[{j}] {obj.name} v={te.visib_fract:.2f}: {te.summary()}", col))
    fps = [i for i in range(len(ests)) if i not in match.values()]
    for i in fps:
        _estimate_overlay(canvas, K, ests[i], objects.get(ests[i].obj_id), s, w, h)
        lines.append((f"false positive: estimate of {objects.get(ests[i].obj_id).name}, score "
                      f"{ests[i].score:.2f}", EST_COLOUR))
    head = f"{run.estimator}: scene {ref.scene_id} image {ref.im_id}  ({len(lines) - len(fps)} targets)"
    return vstack([titled(canvas, head, lines or ["no targets"]), legend_strip(EVAL_LEGEND, canvas.shape[1])], 2)


def failure_cards(run: EvalRun, objects, limit: int, scale: int | None = None) -> list[np.ndarray]:
    """One card per image of ``failures.csv`` (up to ``limit``): the image with its ground truth and the
    failures' kind and message; failures without an image (a whole run) become a text card."""
    from simtest.viz.dataset_page import gt_canvas

    by_image: dict[tuple[int, int], list[dict]] = {}
    loose = []
    for f in run.failures:
        try:
            by_image.setdefault((int(f["scene_id"]), int(f["im_id"])), []).append(f)
        except (KeyError, ValueError):
            loose.append(f)
    keys = list(by_image)[:limit]
    refs = {(r.scene_id, r.im_id): r for r in select_images(run.dataset, run.split,
                                                            sorted({s for s, _ in keys}) or None, None, objects.ids)}
    cards = []
    for key in keys:
        ref = refs.get(key)
        lines = [(f"{f.get('kind', '?')} (obj {f.get('obj_id') or '-'}): {' '.join(str(f.get('message', '')).split())}",
                  BAD_COLOUR) for f in by_image[key]]
        if ref is None:
            cards.append(text_strip([f"scene {key[0]} image {key[1]}: not in the dataset", *lines], 640))
            continue
        rgb = bop.read_image(ref.scene_dir, ref.im_id)
        s = upscale_factor(rgb.shape[1], rgb.shape[0]) if scale is None else int(scale)
        canvas, _ = gt_canvas(ref, objects, s, rgb)
        cards.append(titled(canvas, f"{run.estimator}: scene {key[0]} image {key[1]}", lines))
    if loose:
        cards.append(text_strip([(" ".join(str(f.get("message", "")).split()), BAD_COLOUR) for f in loose], 640))
    return cards


def eval_images(run: EvalRun, objects, sel: ImageSelection) -> list[ImageRef]:
    """The images of ``sel`` (same rules as the dataset page) among the run's evaluated images."""
    done = {(e.scene_id, e.im_id) for e in run.errors}
    refs = select_show_images(run.dataset, ImageSelection(run.split, sel.scene, sel.image, 10 ** 9), objects.ids)
    refs = [r for r in refs if (r.scene_id, r.im_id) in done]
    if not refs:
        raise ConfigError(f"{run.run_dir}: the run scored none of the selected images")
    return refs[:sel.count]
