"""Episode clips: third-person | wrist frames recorded during a scripted episode, with the target's true and
estimated axes drawn into the wrist image (pixels; poses in metres, world frame)."""

from __future__ import annotations

import cv2
import numpy as np

from simtest.envs.task import GraspTask, as_task

__all__ = ["EpisodeRecorder"]


class EpisodeRecorder:
    """Collects third-person | wrist frames every ``every`` control periods. Once ``T_world_obj_est`` (4x4,
    metres) is set, the wrist image shows the target's true frame (thick axes, x red, y green, z blue) and
    the estimated one (thin axes), projected into the current wrist camera."""

    def __init__(self, task: GraspTask, every: int = 2) -> None:
        self.task = as_task(task)
        self.every = max(1, int(every))
        self.frames: list[np.ndarray] = []
        self._k = 0
        self.T_world_obj_est: np.ndarray | None = None

    def _draw_frames(self, wrist: np.ndarray) -> None:
        """The true and estimated target axes on ``wrist`` (the wrist image, possibly resized)."""
        task = self.task
        cam = task.camera_model()
        sx, sy = wrist.shape[1] / cam.width, wrist.shape[0] / cam.height
        K = np.diag([sx, sy, 1.0]) @ cam.K  # pixel centres stay at integers: c' = s (c + 0.5) - 0.5
        K[0, 2], K[1, 2] = sx * (cam.K[0, 2] + 0.5) - 0.5, sy * (cam.K[1, 2] + 0.5) - 0.5
        T_cam_world = cam.T_cam_world.matrix()
        axes = np.vstack([np.zeros(3), np.eye(3) * 0.5 * float(np.max(task.target_obj.size))])
        for T, width in ((task.object_poses_world()[0], 3), (self.T_world_obj_est, 1)):
            p = axes @ (T_cam_world @ T)[:3, :3].T + (T_cam_world @ T)[:3, 3]
            if (p[:, 2] <= 1e-3).any():
                continue
            uv = np.clip(np.round((p @ K.T)[:, :2] / p[:, 2:] * 16), -2 ** 20, 2 ** 20).astype(int)
            for k, col in enumerate(((230, 30, 30), (30, 200, 30), (40, 90, 255))):
                cv2.line(wrist, tuple(uv[0]), tuple(uv[k + 1]), col, width, cv2.LINE_AA, 4)

    def __call__(self, force: bool = False) -> None:
        self._k += 1
        if not force and (self._k - 1) % self.every:
            return
        task = self.task
        tp = task.render_third_person()
        wrist = task.render_wrist_rgb()
        if wrist.shape[0] != tp.shape[0]:
            scale = tp.shape[0] / wrist.shape[0]
            wrist = cv2.resize(wrist, (int(round(wrist.shape[1] * scale)), tp.shape[0]))
        if self.T_world_obj_est is not None:
            wrist = np.array(wrist)
            self._draw_frames(wrist)
        self.frames.append(np.concatenate([tp, wrist], axis=1))
