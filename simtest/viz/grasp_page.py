"""Pictures of a grasp run (``simtest grasp --out RUN``): one card per episode with its outcome and pose error.

A grasp folder holds ``episodes.csv`` (one row per episode: ``success``, ``reason``, ``add_s`` / ``te`` /
``mssd`` metres, ``re_sym_deg`` / ``re_raw_deg`` degrees (``re_deg`` in files of earlier releases),
``lift_height`` metres, ``error``: why a failed episode failed), ``summary.json`` (success rate and its
95 % interval) and, with ``--video``, ``videos/episode_NNNN_<object>_<reason>.gif`` (or ``.mp4``): frames of
third-person view | wrist view. A card shows the clip's first and last frame when the episode has one, else
its text only.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from simtest.io import bop
from simtest.io.files import read_csv
from simtest.viz.draw import BAD_COLOUR, GT_COLOUR
from simtest.viz.sheet import text_strip, titled, vstack

__all__ = ["GRASP_FILES", "is_grasp_run", "episode_clip", "first_last_frames", "episode_lines", "episode_card",
           "grasp_summary_line", "load_episodes"]

#: Files that make a folder a grasp run.
GRASP_FILES = ("episodes.csv", "summary.json")
_CARD_WIDTH = 640


def is_grasp_run(path: Path) -> bool:
    """Whether ``path`` is a grasp run folder (it holds :data:`GRASP_FILES`)."""
    return all((Path(path) / n).is_file() for n in GRASP_FILES)


def load_episodes(run_dir: Path) -> list[dict]:
    """The rows of ``episodes.csv`` (strings, as written)."""
    return read_csv(Path(run_dir) / "episodes.csv")


def episode_clip(run_dir: Path, episode: int) -> Path | None:
    """The episode's clip (``videos/episode_NNNN_*.gif`` or ``.mp4``), or None."""
    clips = sorted((Path(run_dir) / "videos").glob(f"episode_{int(episode):04d}_*"))
    clips = [c for c in clips if c.suffix in (".gif", ".mp4")]
    return clips[0] if clips else None


def first_last_frames(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """First and last frame (RGB uint8) of a GIF (Pillow, frames composed as played) or an MP4 (imageio)."""
    if path.suffix == ".gif":
        from PIL import Image

        with Image.open(path) as im:
            first = np.asarray(im.convert("RGB"))
            im.seek(getattr(im, "n_frames", 1) - 1)
            last = np.asarray(im.convert("RGB"))
        return first, last
    import imageio.v2 as imageio

    with imageio.get_reader(path) as reader:
        frames = [f for f in reader]
    return np.asarray(frames[0])[..., :3], np.asarray(frames[-1])[..., :3]


def _num(row: dict, key: str, old: str | None = None) -> float:
    """``row[key]`` as a number (NaN when empty or missing); ``old``: the column's name in earlier files."""
    value = row.get(key, "")
    if (value is None or value == "") and old is not None:
        value = row.get(old, "")
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan


def episode_lines(row: dict) -> list[tuple[str, tuple[int, int, int]]]:
    """The episode's outcome and pose error as coloured text lines."""
    ok = row.get("success") in ("True", "1", "true")
    col = GT_COLOUR if ok else BAD_COLOUR
    outcome = "success" if ok else f"failed: {row.get('reason')}"
    out = [(f"episode {row.get('episode')}  {row.get('target_name')} (obj {row.get('target_obj_id')}): "
            f"{outcome}, lifted {_num(row, 'lift_height') * 100:.1f} cm", col)]
    if math.isfinite(_num(row, "add_s")):
        re_sym, re_raw = _num(row, "re_sym_deg", "re_deg"), _num(row, "re_raw_deg", "re_deg")
        out.append((f"estimate: ADD-S {_num(row, 'add_s') * 100:.2f} cm  re_sym {re_sym:.1f} deg "
                    f"(raw {re_raw:.1f})  "
                    f"te {_num(row, 'te') * 100:.2f} cm  MSSD {_num(row, 'mssd') * 100:.2f} cm  "
                    f"({_num(row, 'estimate_s') * 1000:.0f} ms)", (235, 235, 235)))
    else:
        out.append(("no pose estimate", BAD_COLOUR))
    if row.get("error"):
        out.append((" ".join(str(row["error"]).split())[:300], BAD_COLOUR))
    return out


def episode_card(run_dir: Path, row: dict) -> np.ndarray:
    """One episode: its clip's first and last frame (third-person | wrist) above its text, or the text only."""
    clip = episode_clip(run_dir, int(row.get("episode", -1)))
    lines = episode_lines(row)
    if clip is None:
        return text_strip(lines + [("(no clip: run simtest grasp with --video)", (150, 150, 150))], _CARD_WIDTH)
    first, last = first_last_frames(clip)
    return vstack([titled(first, "start (third person | wrist)"), titled(last, "end"),
                   text_strip(lines, max(first.shape[1], _CARD_WIDTH))], 2)


def grasp_summary_line(run_dir: Path) -> str:
    """``estimator: 7/10 grasps (70 %, 95 % CI 40-89 %)`` from ``summary.json``."""
    s = bop.read_json(Path(run_dir) / "summary.json")
    ci = s.get("ci95") or [math.nan, math.nan]
    return (f"{s.get('estimator_label', '?')}: {s.get('successes')}/{s.get('episodes')} grasps "
            f"({float(s.get('success_rate', math.nan)) * 100:.0f} %, 95 % CI {ci[0] * 100:.0f}-{ci[1] * 100:.0f} %)  "
            f"{run_dir}")
