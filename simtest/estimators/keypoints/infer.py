"""Inference of the keypoint estimator: network maps -> instance cells -> fused keypoints -> PnP pose.

1. The network predicts, per stride-4 cell, class scores, offsets to the ``J`` projected keypoints and a
   confidence ``c = softplus(z)`` per keypoint (:mod:`simtest.estimators.keypoints.model`).
2. Cells are grouped into instances: with the observation's visible masks (evaluation "with GT masks"), the
   cells each mask covers; otherwise connected components of the cells of each predicted class.
3. Per keypoint, the instance's cells at or above ``min_conf`` are ranked by confidence and the ``top_n`` best
   predictions are averaged with their confidences as weights (:func:`fuse_keypoints`).
4. The pose follows from the fused 2D keypoints and the model's 3D keypoints by EPnP and Levenberg-Marquardt
   refinement (``pnp="epnp"``), or RANSAC EPnP then refinement on the inliers (``pnp="ransac"``)
   (:func:`solve_pnp`).

torch is imported only when a network is loaded or run.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np

from simtest.errors import ConfigError
from simtest.estimators.base import Observation, PoseEstimate
from simtest.estimators.checkpoint import check_objects
from simtest.estimators.keypoints.checkpoint import FORMAT, load_checkpoint
from simtest.estimators.onnx_net import OnnxNet, check_device, resolve_runtime, softmax, softplus

__all__ = ["KeypointEstimator", "fuse_keypoints", "solve_pnp", "mask_cells", "PNP_METHODS", "predict_maps",
           "predict_maps_onnx"]

PNP_METHODS = ("epnp", "sqpnp", "ransac")
#: Fraction of a cell a visible mask must cover for the cell to join the instance (as in training).
MIN_COVERAGE = 0.3


def fuse_keypoints(points: np.ndarray, conf: np.ndarray, top_n: int = 16,
                   min_conf: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Confidence-weighted fusion of per-cell keypoint predictions.

    Args:
        points: (M, J, 2) predicted keypoint positions (pixels) of the M cells of one instance.
        conf: (M, J) confidences (> 0).
        top_n: Predictions fused per keypoint (the most confident ones).
        min_conf: Predictions below this confidence are ignored (if none is left, the single best is used).

    Returns:
        ``(keypoints (J, 2) pixels, confidence (J,))``: the weighted means and the mean confidence of the
        fused predictions.
    """
    points = np.asarray(points, np.float64)
    conf = np.asarray(conf, np.float64)
    if points.ndim != 3 or points.shape[0] == 0:
        raise ConfigError(f"fuse_keypoints needs (M >= 1, J, 2) points, got shape {points.shape}")
    M, J, _ = points.shape
    kp = np.zeros((J, 2))
    kc = np.zeros(J)
    for j in range(J):
        order = np.argsort(-conf[:, j], kind="stable")
        keep = order[conf[order, j] >= min_conf][:max(1, int(top_n))]
        if len(keep) == 0:
            keep = order[:1]
        w = np.maximum(conf[keep, j], 1e-12)
        kp[j] = (w[:, None] * points[keep, j]).sum(0) / w.sum()
        kc[j] = float(conf[keep, j].mean())
    return kp, kc


def solve_pnp(kp2d: np.ndarray, kp3d: np.ndarray, K: np.ndarray, method: str = "epnp",
              ransac_px: float = 8.0) -> tuple[np.ndarray, np.ndarray, float]:
    """Pose from 2D-3D keypoint correspondences.

    Args:
        kp2d: (J, 2) pixels. kp3d: (J, 3) model frame, metres. K: 3x3 intrinsics.
        method: ``"epnp"`` (EPnP then LM refinement on all points), ``"sqpnp"`` (SQPnP, globally optimal for
            its algebraic error, then LM) or ``"ransac"`` (RANSAC EPnP with ``ransac_px`` reprojection
            threshold, then LM on the inliers).

    Returns:
        ``(R (3, 3), t (3,) metres, rms reprojection error in pixels)``.

    Raises:
        ConfigError: Unknown method or fewer than 4 points. ValueError: PnP failed.
    """
    if method not in PNP_METHODS:
        raise ConfigError(f"unknown PnP method {method!r}; valid: {', '.join(PNP_METHODS)}")
    obj = np.ascontiguousarray(kp3d, np.float64).reshape(-1, 1, 3)
    img = np.ascontiguousarray(kp2d, np.float64).reshape(-1, 1, 2)
    if len(obj) < 4:
        raise ConfigError(f"PnP needs at least 4 keypoints, got {len(obj)}")
    K = np.asarray(K, np.float64)
    inl = np.arange(len(obj))
    if method == "ransac":
        ok, rvec, tvec, idx = cv2.solvePnPRansac(obj, img, K, None, iterationsCount=100,
                                                 reprojectionError=float(ransac_px), confidence=0.99,
                                                 flags=cv2.SOLVEPNP_EPNP)
        if ok and idx is not None and len(idx) >= 4:
            inl = idx.flatten()
        else:
            ok, rvec, tvec = cv2.solvePnP(obj, img, K, None, flags=cv2.SOLVEPNP_EPNP)
    else:
        flag = cv2.SOLVEPNP_SQPNP if method == "sqpnp" else cv2.SOLVEPNP_EPNP
        ok, rvec, tvec = cv2.solvePnP(obj, img, K, None, flags=flag)
    if not ok:
        raise ValueError(f"PnP ({method}) failed")
    rvec, tvec = cv2.solvePnPRefineLM(obj[inl], img[inl], K, None, rvec, tvec,
                                      criteria=(cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 50, 1e-12))
    R, _ = cv2.Rodrigues(rvec)
    t = tvec.reshape(3)
    proj, _ = cv2.projectPoints(obj, rvec, tvec, K, None)
    rms = float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - img.reshape(-1, 2)) ** 2, axis=1))))
    if t[2] <= 0 or not np.all(np.isfinite(R)) or not np.all(np.isfinite(t)):
        raise ValueError(f"PnP gave an invalid pose (t = {t.tolist()} m)")
    return R, t, rms


def mask_cells(mask: np.ndarray, grid: tuple[int, int], stride: int) -> np.ndarray:
    """(h, w) bool cells covered by ``mask`` (H, W): coverage >= :data:`MIN_COVERAGE`, or any pixel if no cell
    reaches it (small or thin instances)."""
    h, w = grid
    m = np.zeros((h * stride, w * stride), np.float32)
    H, W = mask.shape
    m[:min(H, h * stride), :min(W, w * stride)] = mask[:h * stride, :w * stride]
    cov = m.reshape(h, stride, w, stride).mean(axis=(1, 3))
    cells = cov >= MIN_COVERAGE
    return cells if cells.any() else cov > 0


def predict_maps(model: Any, rgb: np.ndarray, device: str = "cpu") -> dict[str, np.ndarray]:
    """Run the network on one image.

    Args:
        model: A :class:`~simtest.estimators.keypoints.model.KeypointNet` (eval mode is set here).
        rgb: (H, W, 3) uint8.

    Returns:
        ``seg`` (C+1, h, w) class probabilities, ``points`` (J, 2, h, w) predicted keypoint positions in pixels,
        ``conf`` (J, h, w) confidences ``softplus(z)``; the grid covers the image padded to a multiple of 16.
    """
    import torch
    from torch.nn import functional as F

    from simtest.estimators.keypoints.model import cell_centers

    H, W = rgb.shape[:2]
    ph, pw = (-H) % 16, (-W) % 16
    x = torch.from_numpy(np.ascontiguousarray(rgb.transpose(2, 0, 1))).to(torch.float32).div_(255.0)
    x = F.pad(x, (0, pw, 0, ph))[None].to(device)
    model.eval()
    with torch.inference_mode():
        out = model(x)
    cfg = model.cfg
    h, w = out["seg"].shape[-2:]
    centers = cell_centers(h, w, cfg.stride, device)
    points = out["offsets"][0] * cfg.offset_scale + centers[None]
    return {"seg": torch.softmax(out["seg"][0], 0).cpu().numpy(), "points": points.cpu().numpy().astype(np.float64),
            "conf": F.softplus(out["conf_logit"][0]).cpu().numpy().astype(np.float64)}


def predict_maps_onnx(net: Any, rgb: np.ndarray) -> dict[str, np.ndarray]:
    """:func:`predict_maps` through an exported network (:class:`~simtest.estimators.onnx_net.OnnxNet`), without
    torch: the same maps (to float32 rounding)."""
    cfg = net.meta["net"]
    H, W = rgb.shape[:2]
    x = rgb.transpose(2, 0, 1).astype(np.float32) / np.float32(255.0)
    x = np.pad(x, ((0, 0), (0, (-H) % 16), (0, (-W) % 16)))[None]
    seg, offsets, conf_logit = net.run(x)
    h, w = seg.shape[-2:]
    stride = int(cfg.get("stride", 4))
    gx = np.arange(w, dtype=np.float32) * stride + (stride - 1) / 2.0
    gy = np.arange(h, dtype=np.float32) * stride + (stride - 1) / 2.0
    centers = np.stack(np.meshgrid(gx, gy, indexing="xy"))  # (2, h, w): x, y
    points = offsets[0] * np.float32(cfg["offset_scale"]) + centers[None]
    return {"seg": softmax(seg[0], 0), "points": points.astype(np.float64),
            "conf": softplus(conf_logit[0]).astype(np.float64)}


class KeypointEstimator:
    """Confidence-based keypoint pose estimator (registered as ``keypoints``).

    Args:
        checkpoint: A model file written by ``simtest train keypoints`` (``model.pt``, ``best.pt`` or
            ``last.pt``).
        device: ``"cpu"`` or ``"cuda"``.
        top_n: Predictions fused per keypoint.
        min_conf: Confidence threshold of the fused predictions (confidence = 1 / expected offset error in
            units of the network's ``offset_scale`` pixels).
        pnp: ``"epnp"`` or ``"ransac"`` (see :func:`solve_pnp`).
        use_masks: Group cells with the targets' ground-truth visible masks (the estimator then declares
            ``needs_gt_masks``); False: by the predicted segmentation, reading no ground truth.
        min_cells: Smallest connected component (cells) kept as an instance in segmentation mode.
        threads: CPU threads of the network (None: torch's default; 1 for ONNX Runtime).
        runtime: ``auto`` (the checkpoint's ONNX file when it is current, else torch), ``onnx`` or ``torch``
            (:func:`simtest.estimators.onnx_net.resolve_runtime`); a ``.onnx`` checkpoint runs without torch.

    Raises:
        ConfigError: Missing or unreadable checkpoint, bad options; at :meth:`estimate`, an observation whose
            object set differs from the one the checkpoint was trained for.
    """

    def __init__(self, checkpoint: str | Path | None = None, device: str = "cpu", top_n: int = 16,
                 min_conf: float = 0.0, pnp: str = "epnp", use_masks: bool = True, min_cells: int = 3,
                 threads: int | None = None, runtime: str = "auto", *, model: Any = None,
                 objects_record: dict[str, Any] | None = None) -> None:
        if pnp not in PNP_METHODS:
            raise ConfigError(f"keypoints: unknown pnp {pnp!r}; valid: {', '.join(PNP_METHODS)}")
        if int(top_n) < 1:
            raise ConfigError(f"keypoints: top_n must be >= 1, got {top_n!r}")
        check_device(device, "keypoints")
        self.checkpoint = None if checkpoint is None else str(checkpoint)
        self.net = None
        if model is None:
            if checkpoint is None:
                raise ConfigError("keypoints: give checkpoint=PATH (a model file from `simtest train keypoints`)")
            self.runtime, path = resolve_runtime(Path(checkpoint), runtime, "keypoints")
            self.checkpoint = str(path)
        else:
            self.runtime = "torch"
            if objects_record is None:
                raise ConfigError("keypoints: a model given in memory needs its objects_record")
        if self.runtime == "onnx":
            if device != "cpu":
                raise ConfigError(f"keypoints: the ONNX runtime runs on the CPU; device={device!r} needs "
                                  "runtime=torch and a .pt checkpoint")
            self.net = OnnxNet(path, FORMAT, threads)
            objects_record, self.stride = self.net.meta["objects"], int(self.net.meta["net"].get("stride", 4))
            self.model = None
        else:
            import torch

            from simtest.estimators.keypoints.model import KeypointNet, NetConfig

            if threads is not None:
                torch.set_num_threads(int(threads))
            if model is None:
                ckpt = load_checkpoint(path, map_location="cpu")
                model = KeypointNet(NetConfig.from_dict(ckpt["net"]))
                model.load_state_dict(ckpt["model"])
                objects_record = ckpt["objects"]
            self.model = model.to(device).eval()
            self.stride = int(self.model.cfg.stride)
        self.device = device
        self.record = objects_record
        self.class_ids = [int(i) for i in objects_record["obj_ids"]]
        self.kp3d = {int(i): np.asarray(k, np.float64) for i, k in zip(objects_record["obj_ids"],
                                                                        objects_record["keypoints"])}
        self.top_n = int(top_n)
        self.min_conf = float(min_conf)
        self.pnp = pnp
        self.use_masks = bool(use_masks)
        #: Ground-truth visible masks are passed (and the runs labelled ``(GT masks)``) only when used.
        self.needs_gt_masks = self.use_masks
        #: RGB only: the observation's depth is never read.
        self.needs_depth = False
        self.min_cells = int(min_cells)
        self.last_failures: list[dict[str, Any]] = []
        self._checked: set[int] = set()

    def __repr__(self) -> str:
        return (f"KeypointEstimator(checkpoint={self.checkpoint!r}, device={self.device!r}, top_n={self.top_n}, "
                f"min_conf={self.min_conf}, pnp={self.pnp!r})")

    def check_objects(self, objects: Any) -> None:
        """Raise :class:`ConfigError` unless ``objects`` is the set the network was trained for."""
        if id(objects) in self._checked:
            return
        check_objects(self.record, objects, where=f"keypoints checkpoint {self.checkpoint or '(in memory)'}")
        self._checked.add(id(objects))

    def _pose(self, maps: dict[str, np.ndarray], cells: np.ndarray, obj_id: int, K: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray, float, dict[str, Any]]:
        pts = maps["points"][:, :, cells].transpose(2, 0, 1)  # (M, J, 2)
        conf = maps["conf"][:, cells].T  # (M, J)
        kp, kc = fuse_keypoints(pts, conf, self.top_n, self.min_conf)
        R, t, rms = solve_pnp(kp, self.kp3d[obj_id], K, self.pnp)
        mc = float(kc.mean())
        return R, t, mc / (1.0 + mc), {"cells": int(cells.sum()), "reproj_rms_px": rms,
                                       "keypoints_2d": kp.tolist(), "keypoint_conf": kc.tolist()}

    def estimate(self, observation: Observation) -> list[PoseEstimate]:
        """Pose estimates (metres) for the observation's targets, or for every segmented instance."""
        obs = observation
        self.check_objects(obs.objects)
        self.last_failures = []
        maps = predict_maps_onnx(self.net, obs.rgb) if self.net is not None else predict_maps(self.model, obs.rgb,
                                                                                                  self.device)
        h, w = maps["conf"].shape[-2:]
        stride = self.stride
        K = np.asarray(obs.K, np.float64)
        out: list[PoseEstimate] = []
        groups: list[tuple[int | None, int, np.ndarray]] = []  # (target index, obj_id, cells)
        if obs.target_obj_ids is not None and obs.masks is not None and self.use_masks:
            for k, (oid, m) in enumerate(zip(obs.target_obj_ids, obs.masks)):
                groups.append((k, int(oid), mask_cells(np.asarray(m, bool), (h, w), stride)))
        else:
            label = maps["seg"].argmax(0)
            want = set(obs.target_obj_ids) if obs.target_obj_ids is not None else set(self.class_ids)
            for c, oid in enumerate(self.class_ids, start=1):
                if oid not in want:
                    continue
                n, comp = cv2.connectedComponents((label == c).astype(np.uint8), connectivity=8)
                for lab in range(1, n):
                    cells = comp == lab
                    if cells.sum() >= self.min_cells:
                        groups.append((None, oid, cells))
        for k, oid, cells in groups:
            if oid not in self.kp3d:
                self.last_failures.append({"obj_id": oid, "reason": f"object {oid} not in the trained set"})
                continue
            if not cells.any():
                self.last_failures.append({"obj_id": oid, "reason": "visible mask covers no cell"})
                continue
            try:
                R, t, score, info = self._pose(maps, cells, oid, K)
            except (ValueError, cv2.error) as exc:
                self.last_failures.append({"obj_id": oid, "reason": f"PnP failed: {exc}"})
                continue
            if k is None:
                score *= float(maps["seg"][self.class_ids.index(oid) + 1][cells].mean())
            out.append(PoseEstimate(obj_id=oid, R=R, t=t, score=float(score), target_index=k, info=info))
        return out
