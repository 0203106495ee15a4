"""``simtest show PATH``: tell a dataset, an evaluation run and a grasp run apart by their files, draw the
asked-for cards and write them as one PNG contact sheet (``--out FILE.png``) or one PNG per card (``--out DIR``).

* dataset (``PATH/<split>/<6-digit scene>/``): :mod:`simtest.viz.dataset_page`, one card per image;
* evaluation folder (``metrics.json`` + ``errors.csv``): :mod:`simtest.viz.eval_page`, one card per image,
  per target with ``worst``, per failed image with ``failures``;
* grasp run (``episodes.csv`` + ``summary.json``): :mod:`simtest.viz.grasp_page`, one card per episode.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from simtest.errors import ConfigError, DatasetError
from simtest.viz import eval_page, grasp_page
from simtest.viz.dataset_page import ImageSelection, dataset_card, load_captions, select_show_images
from simtest.viz.sheet import grid, save_png, text_strip, vstack

__all__ = ["ShowOptions", "ShowResult", "show", "folder_kind", "SHEET_MAX_WIDTH"]

#: Widest contact sheet laid out (pixels): cards per row are chosen to stay below it.
SHEET_MAX_WIDTH = 2600


@dataclass(frozen=True)
class ShowOptions:
    """What to draw. ``selection``: the images (dataset and evaluation pages); ``worst``: the N worst targets
    by ``by``; ``failures``: the images of ``failures.csv``; ``data``: the dataset of an evaluation run (default:
    the one its ``metrics.json`` names); ``scale``: integer upscale (None: small images to >= 480 rows);
    ``episodes``: at most this many grasp episodes; ``palette``: 256-colour PNGs."""

    selection: ImageSelection = field(default_factory=ImageSelection)
    worst: int | None = None
    by: str = "mssd"
    failures: bool = False
    data: str | Path | None = None
    scale: int | None = None
    episodes: int = 12
    palette: bool = False


@dataclass(frozen=True)
class ShowResult:
    """What was written: the kind of folder shown, the PNG paths, the number of cards and the mean drawing
    time per card (milliseconds, reading included, writing excluded)."""

    kind: str
    paths: list[Path]
    cards: int
    ms_per_card: float


def folder_kind(path: Path, split: str | None = None) -> str:
    """``"eval"``, ``"grasp"`` or ``"dataset"``.

    Raises:
        DatasetError: ``path`` does not exist or is none of the three (naming what each needs).
    """
    path = Path(path)
    if not path.exists():
        raise DatasetError(f"{path} does not exist")
    if eval_page.is_eval_run(path):
        return "eval"
    if grasp_page.is_grasp_run(path):
        return "grasp"
    if path.is_dir() and ((split is not None and (path / split).is_dir()) or (path / "camera.json").is_file() or any(
            c.is_dir() and any(s.is_dir() and s.name.isdigit() and len(s.name) == 6 for s in c.iterdir())
            for c in path.iterdir())):
        return "dataset"
    raise DatasetError(f"{path} is not a BOP dataset (DATASET/{split or '<split>'}/<6-digit scene>/), an evaluation "
                       "folder (metrics.json, errors.csv) or a grasp run (episodes.csv, summary.json)")


def _dataset_cards(path: Path, opts: ShowOptions) -> list[np.ndarray]:
    from simtest.objects.loaders import load_dataset_objects

    objects = load_dataset_objects(path)
    refs = select_show_images(path, opts.selection, objects.ids)
    captions: dict[Path, dict | None] = {}
    cards = []
    for ref in refs:
        if ref.gt_dir not in captions:
            captions[ref.gt_dir] = load_captions(ref.gt_dir)
        cards.append(dataset_card(ref, objects, opts.scale, captions[ref.gt_dir]))
    return cards


def _eval_cards(path: Path, opts: ShowOptions) -> list[np.ndarray]:
    from simtest.objects.loaders import load_dataset_objects

    run = eval_page.load_eval_run(path, opts.data)
    objects = load_dataset_objects(run.dataset)
    head = text_strip([f"{run.estimator} on {run.dataset} ({run.split}): {len(run.errors)} targets, "
                       f"{sum(e.correct for e in run.errors)} correct (ADD(-S) < 0.1d), "
                       f"{sum(not e.matched for e in run.errors)} missed, {len(run.failures)} failures"], 1280)
    if opts.failures:
        if not run.failures:
            raise ConfigError(f"{path / 'failures.csv'} lists no failure")
        return [head, *eval_page.failure_cards(run, objects, opts.selection.count if opts.worst is None
                                               else opts.worst, opts.scale)]
    if opts.worst is not None:
        targets = eval_page.worst_targets(run, opts.worst, opts.by)
        index = eval_page.image_index(run, objects, [(t.scene_id, t.im_id) for t in targets])
        return [head, *(eval_page.target_card(run, objects, t, index, opts.scale) for t in targets)]
    refs = eval_page.eval_images(run, objects, opts.selection)
    keys = [(r.scene_id, r.im_id) for r in refs]
    index = eval_page.image_index(run, objects, keys, refs)
    return [head, *(eval_page.image_card(run, objects, k, index, opts.scale) for k in keys)]


def _grasp_cards(path: Path, opts: ShowOptions) -> list[np.ndarray]:
    rows = grasp_page.load_episodes(path)
    if not rows:
        raise DatasetError(f"{path / 'episodes.csv'} lists no episode")
    head = text_strip([grasp_page.grasp_summary_line(path)], 1280)
    return [head, *(grasp_page.episode_card(path, r) for r in rows[:max(1, opts.episodes)])]


def show(path: str | Path, out: str | Path, opts: ShowOptions | None = None) -> ShowResult:
    """Draw ``path`` (a dataset, evaluation or grasp folder) into ``out``: a ``.png`` file (one contact
    sheet; the first card of evaluation and grasp pages is their one-line summary) or a folder (one PNG per
    card, ``card_NNN.png``).

    Raises:
        DatasetError: ``path`` is not a folder simtest can show, or its files are malformed.
        ConfigError: A selection that matches nothing (a scene or image that does not exist).
    """
    path, out, opts = Path(path), Path(out), opts or ShowOptions()
    kind = folder_kind(path, opts.selection.split)
    t0 = time.perf_counter()
    cards = {"dataset": _dataset_cards, "eval": _eval_cards, "grasp": _grasp_cards}[kind](path, opts)
    ms = (time.perf_counter() - t0) * 1000.0 / max(1, len(cards) - (kind != "dataset"))
    if out.suffix.lower() == ".png":
        head, body = (cards[0], cards[1:]) if kind != "dataset" else (None, cards)
        width = max(c.shape[1] for c in body)
        cols = max(1, min(math.ceil(math.sqrt(len(body))), SHEET_MAX_WIDTH // max(1, width)))
        sheet = grid(body, cols)
        if head is not None:
            sheet = vstack([_widen(head, sheet.shape[1]), sheet])
        paths = [save_png(out, sheet, opts.palette)]
    else:
        out.mkdir(parents=True, exist_ok=True)
        paths = [save_png(out / f"card_{i:03d}.png", c, opts.palette) for i, c in enumerate(cards)]
    return ShowResult(kind, paths, len(cards) - (kind != "dataset"), ms)


def _widen(strip: np.ndarray, width: int) -> np.ndarray:
    if strip.shape[1] >= width:
        return strip[:, :width]
    pad = np.repeat(strip[:, -1:], width - strip.shape[1], axis=1)
    return np.hstack([strip, pad])
