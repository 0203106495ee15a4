"""``simtest show GRASP_RUN`` on a real grasp run with a clip, whose wrist view carries the target's axes once
the estimate is known, and on a run without clips."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from simtest.cli import main
from simtest.viz.grasp_page import episode_clip, first_last_frames

GREEN_AXIS = np.array([30, 200, 30])


@pytest.fixture(scope="module")
def grasp_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("grasp") / "run"
    assert main(["grasp", "--quiet", "--estimator", "oracle", "--opt", "rot_noise_deg=20", "--episodes", "1",
                 "--width", "160", "--height", "120", "--video", "--out", str(out)]) == 0
    return out


def _near(img: np.ndarray, colour: np.ndarray, tol: int = 40) -> int:
    return int((np.abs(img.astype(int) - colour).max(axis=-1) < tol).sum())


def test_wrist_view_shows_the_axes_after_the_estimate(grasp_run):
    from PIL import Image

    clip = episode_clip(grasp_run, 0)
    assert clip is not None and clip.suffix in (".gif", ".mp4")
    if clip.suffix != ".gif":
        pytest.skip("an ffmpeg backend wrote an MP4")
    with Image.open(clip) as im:
        frames = []
        for k in range(im.n_frames):
            im.seek(k)
            frames.append(np.asarray(im.convert("RGB")))
    half = frames[0].shape[1] // 2  # third person | wrist, both 320 px wide at this size
    assert _near(frames[0][:, half:], GREEN_AXIS) == 0  # observing: no estimate yet
    assert max(_near(f[:, half:], GREEN_AXIS) for f in frames) > 10


def test_grasp_page_shows_first_and_last_frame_and_the_outcome(grasp_run, tmp_path, capsys):
    out = tmp_path / "grasp.png"
    assert main(["show", str(grasp_run), "--out", str(out)]) == 0
    assert "grasp: 1 episode" in capsys.readouterr().out
    img = cv2.imread(str(out))
    first, last = first_last_frames(episode_clip(grasp_run, 0))
    assert img.shape[1] == first.shape[1] and img.shape[0] > first.shape[0] + last.shape[0]


def test_grasp_page_without_clips_is_a_table(grasp_run, tmp_path):
    import shutil

    bare = tmp_path / "bare"
    bare.mkdir()
    for name in ("episodes.csv", "summary.json"):
        shutil.copy(grasp_run / name, bare / name)
    out = tmp_path / "bare.png"
    assert main(["show", str(bare), "--out", str(out)]) == 0
    img = cv2.imread(str(out))
    assert img.shape[1] >= 640 and img.shape[0] < 200
