"""Video files of frame sequences: MP4 when an ffmpeg backend is installed, else GIF (the grasp runs' videos)."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import imageio.v2 as imageio
import numpy as np

__all__ = ["write_video"]


def write_video(frames: Sequence[np.ndarray], path: str | Path, fps: float = 10.0) -> Path:
    """Write frames (H, W, 3) uint8 as an MP4 if an ffmpeg backend is installed, else as a GIF.

    Args:
        frames: The frames.
        path: Output path (its suffix is replaced by ``.mp4`` or ``.gif``).
        fps: Frames per second of playback; a GIF stores ``1000 / fps`` ms per frame (imageio's GIF writer
            takes ``duration`` in milliseconds), rounded by the format to 10 ms. GIF frames wider than 640 px
            are halved in both directions.

    Returns:
        The path written (suffix ``.mp4`` or ``.gif``).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        import imageio_ffmpeg  # noqa: F401  (optional: MP4 only when installed)

        path = path.with_suffix(".mp4")
        imageio.mimwrite(path, list(frames), fps=fps, macro_block_size=1)
    except ImportError:
        path = path.with_suffix(".gif")
        imageio.mimwrite(path, [f[::2, ::2] if f.shape[1] > 640 else f for f in frames],
                         duration=1000.0 / fps, loop=0)
    return path
