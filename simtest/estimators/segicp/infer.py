"""Inference of ``segicp``: RGB (optionally RGB-D) -> per-class segmentation -> one region per found object ->
its pose from depth by the coarse rotation search + ICP of :mod:`simtest.estimators.icp`.

1. :class:`Segmenter` runs the network (:mod:`.model`) on the image. When the observation's focal length
   differs from the training images' by more than 10 %, the image is resized by ``f_train / f_obs`` first
   (objects then appear at the size the network learned), and the labels are resized back (nearest).
2. Regions: the connected components (8-connected) of each class's pixels with at least
   ``min_region_pixels`` pixels, largest first. With ``Observation.target_obj_ids`` (the objects to look for,
   as BOP's localisation task gives them; not ground truth about where they are) only those classes are
   kept, as many components per class as the id occurs; otherwise every component.
3. Each region is fitted by :meth:`simtest.estimators.icp.ICPEstimator.fit_mask`; the estimate's score is the
   ICP fitness times the region's mean class probability.

The observation's ground-truth masks, boxes and poses are never read (the evaluation does not pass them:
``needs_gt_masks`` is False).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from simtest.errors import ConfigError
from simtest.estimators.base import Observation, PoseEstimate
from simtest.estimators.checkpoint import check_objects, load_checkpoint
from simtest.estimators.icp import ICPEstimator
from simtest.estimators.onnx_net import OnnxNet, check_device, resolve_runtime, softmax
from simtest.estimators.segicp.inputs import DEPTH_RANGE_M, depth_channel_np, size_multiple

__all__ = ["Segmenter", "SegICPEstimator", "estimate_segmented", "default_checkpoint", "DEFAULT_CHECKPOINT_NAME",
           "FORMAT", "DEPTH_RANGE_M", "depth_channel_np", "size_multiple"]

#: ``format`` entry of segmentation checkpoints.
FORMAT = "simtest-segmentation/1"
#: How :meth:`Segmenter.regions` orders the regions of one class.
REGION_RANKS = ("area", "prob")
#: File name of the shipped checkpoint (in ``simtest/estimators/weights/``).
DEFAULT_CHECKPOINT_NAME = "segicp_builtin-small_320x240.pt"


def default_checkpoint() -> Path:
    """The shipped segmentation checkpoint (``builtin-small`` objects, 320x240 images): package data next to
    the estimators, so it is found in an editable install and in a wheel alike. Its ONNX file
    (:func:`~simtest.estimators.onnx_net.onnx_path_for`) lies beside it and is what inference runs."""
    return Path(__file__).resolve().parent.parent / "weights" / DEFAULT_CHECKPOINT_NAME


class Segmenter:
    """The segmentation network of a checkpoint from ``simtest train segmentation``, run by ONNX Runtime (no
    torch) or by torch.

    Args:
        checkpoint: Checkpoint (``model.pt``, ``best.pt``, ``last.pt``) or its ONNX file (``model.onnx``);
            None: :func:`default_checkpoint` (through its shipped ONNX file).
        device: ``cpu`` or ``cuda`` (torch only; ONNX Runtime runs on the CPU).
        min_region_pixels: Smallest connected component (pixels, at the observation's resolution) kept.
        threads: CPU threads of the network (None: torch's default; 1 for ONNX Runtime, whose outputs do not
            depend on it).
        erode_px: Each region is eroded by this many pixels before fitting (0: not at all).
        flip: Average the class probabilities of the image and of its mirror image (test-time augmentation:
            +0.4 points ADD(-S)-0.1d on the README's test set with a 28-epoch network, for a second pass).
        runtime: ``auto``, ``onnx`` or ``torch`` (:func:`simtest.estimators.onnx_net.resolve_runtime`).

    Raises:
        ConfigError: A missing or unreadable checkpoint, bad options, torch needed but missing.
    """

    def __init__(self, checkpoint: str | Path | None = None, device: str = "cpu", min_region_pixels: int = 40,
                 threads: int | None = None, erode_px: int = 0, flip: bool = True, runtime: str = "auto") -> None:
        if int(min_region_pixels) < 1:
            raise ConfigError(f"segicp: min_region_pixels must be >= 1, got {min_region_pixels!r}")
        check_device(device, "segicp")
        self.shipped = checkpoint is None
        path = default_checkpoint() if checkpoint is None else Path(checkpoint)
        if self.shipped and not path.is_file():
            raise ConfigError(f"segicp: the shipped checkpoint {str(path)!r} is missing; train one with "
                              "`simtest train segmentation` and pass --opt checkpoint=PATH")
        self.runtime, path = resolve_runtime(path, runtime, "segicp")
        if self.runtime == "onnx" and device != "cpu":
            raise ConfigError(f"segicp: the ONNX runtime runs on the CPU; device={device!r} needs runtime=torch "
                              "and a .pt checkpoint")
        self.checkpoint = str(path)
        if self.runtime == "onnx":
            self.net = OnnxNet(path, FORMAT, threads)
            meta = self.net.meta
            self.depth_input = bool(meta["net"].get("depth_input", False))
            self.record, focal = meta["objects"], meta["focal_px"]
            self.multiple = size_multiple(meta["net"])
        else:
            import torch

            from simtest.estimators.segicp.model import SegNet, SegNetConfig

            if threads is not None:
                torch.set_num_threads(int(threads))
            ckpt = load_checkpoint(path, fmt=FORMAT)
            self.model = SegNet(SegNetConfig.from_dict(ckpt["net"]))
            self.model.load_state_dict(ckpt["model"])
            self.model.to(device).eval()
            self.depth_input = bool(self.model.cfg.depth_input)
            self.record, focal = ckpt["objects"], ckpt.get("focal_px", 0.0)
            self.multiple = size_multiple(ckpt["net"])
        self.device = device
        self.class_ids = [int(i) for i in self.record["obj_ids"]]
        self.focal_px = float(focal)
        self.min_region_pixels = int(min_region_pixels)
        self.erode_px = int(erode_px)
        self.flip = bool(flip)
        self._checked: set[int] = set()

    def check_objects(self, objects: Any) -> None:
        """Raise :class:`ConfigError` unless ``objects`` holds the objects the network was trained for (same
        ids and meshes; other objects may be there too, the network does not look for them)."""
        if id(objects) in self._checked:
            return
        where = f"segicp checkpoint {self.checkpoint}" + (" (the shipped one)" if self.shipped else "")
        known = set(int(i) for i in getattr(objects, "ids", []))
        check_objects(self.record, objects.subset(self.class_ids) if known >= set(self.class_ids) else objects,
                      where=where, hint="For other objects train a network (simtest generate --objects SET ...; "
                                        "simtest train segmentation --data DATASET --out RUN) and pass --opt "
                                        "checkpoint=RUN/model.pt")
        self._checked.add(id(objects))

    def probabilities(self, rgb: np.ndarray, depth: np.ndarray, K: np.ndarray) -> np.ndarray:
        """(C+1, H, W) class probabilities of one image (``rgb`` (H, W, 3) uint8, ``depth`` (H, W) metres); with
        ``flip``, the mean of the image's and its mirror image's (mirrored back)."""
        H, W = rgb.shape[:2]
        scale = self.focal_px / float(K[0, 0]) if self.focal_px > 0 else 1.0
        if abs(scale - 1.0) > 0.1:
            size = (max(16, int(round(W * scale))), max(16, int(round(H * scale))))
            rgb = cv2.resize(rgb, size, interpolation=cv2.INTER_AREA if scale < 1 else cv2.INTER_LINEAR)
            depth = cv2.resize(np.asarray(depth, np.float32), size, interpolation=cv2.INTER_NEAREST)
        h, w = rgb.shape[:2]
        prob = self._onnx_probabilities(rgb, depth) if self.runtime == "onnx" else self._torch_probabilities(rgb, depth)
        if (h, w) != (H, W):
            prob = np.stack([cv2.resize(p, (W, H), interpolation=cv2.INTER_LINEAR) for p in prob])
        return prob

    def _onnx_probabilities(self, rgb: np.ndarray, depth: np.ndarray) -> np.ndarray:
        h, w = rgb.shape[:2]
        chans = [rgb.transpose(2, 0, 1).astype(np.float32) / np.float32(255.0)]
        if self.depth_input:
            chans.append(depth_channel_np(np.asarray(depth, np.float32))[None])
        m = self.multiple
        x = np.pad(np.concatenate(chans, 0), ((0, 0), (0, (-h) % m), (0, (-w) % m)))
        x = np.stack([x, x[..., ::-1]]) if self.flip else x[None]  # the image and its mirror image in one batch
        prob = softmax(self.net.run(x)[0][:, :, :h, :w], axis=1)
        return np.ascontiguousarray(0.5 * (prob[0] + prob[1][..., ::-1]) if self.flip else prob[0])

    def _torch_probabilities(self, rgb: np.ndarray, depth: np.ndarray) -> np.ndarray:
        import torch

        from simtest.estimators.segicp.model import net_input

        h, w = rgb.shape[:2]
        x = torch.from_numpy(np.ascontiguousarray(rgb.transpose(2, 0, 1))).to(torch.float32).div_(255.0)[None]
        d = torch.from_numpy(np.asarray(depth, np.float32))[None, None]
        if self.flip:  # the image and its mirror image in one batch
            x, d = torch.cat([x, x.flip(-1)]), torch.cat([d, d.flip(-1)])
        with torch.inference_mode():
            prob = self.model(net_input(x, d, self.depth_input, self.multiple).to(self.device))[:, :, :h, :w].softmax(1)
        return (0.5 * (prob[0] + prob[1].flip(-1)) if self.flip else prob[0]).cpu().numpy()

    def _erode(self, mask: np.ndarray) -> np.ndarray:
        """``mask`` eroded by ``erode_px`` pixels (the region's rim, where a predicted mask most often bleeds
        onto the background's depth, is dropped); the mask itself if too little would be left."""
        if self.erode_px <= 0:
            return mask
        k = np.ones((2 * self.erode_px + 1,) * 2, np.uint8)
        inner = cv2.erode(mask.astype(np.uint8), k).astype(bool)
        return inner if np.count_nonzero(inner) >= max(self.min_region_pixels // 2, 1) else mask

    def regions(self, obs: Observation, per_instance: int = 1, rank: str = "area", threshold: float = 0.0
                ) -> list[tuple[int, np.ndarray, float]]:
        """``(obj_id, mask (H, W) bool, mean class probability)`` per found object (see the module doc).

        ``per_instance``: with target ids, up to this many regions per expected instance, as candidates for a
        caller that checks them (``keypoints --opt candidates=N``). ``rank``: which regions of a class come
        first, ``"area"`` (largest first) or ``"prob"`` (highest mean class probability first: on real
        photographs clutter a network trained on renders takes for an object is large but less certain).
        ``threshold``: 0 takes a class's regions from the class map (the pixels where the class is the most
        probable); above 0, from the pixels where the class's probability exceeds it, so an object whose pixels
        another class narrowly wins still gets a region (regions of different classes may then overlap)."""
        if rank not in REGION_RANKS:  # checked before the network runs (again in regions_in)
            raise ConfigError(f"region rank must be one of {', '.join(REGION_RANKS)}, got {rank!r}")
        return self.regions_in(self.probabilities(obs.rgb, obs.depth, np.asarray(obs.K, np.float64)), obs,
                               per_instance, rank, threshold)

    def regions_in(self, prob: np.ndarray, obs: Observation, per_instance: int = 1, rank: str = "area",
                   threshold: float = 0.0) -> list[tuple[int, np.ndarray, float]]:
        """:meth:`regions` from class probabilities already computed for ``obs`` (``prob`` (C+1, H, W) of
        :meth:`probabilities`), so one image's regions can be taken several ways for one network run."""
        if rank not in REGION_RANKS:
            raise ConfigError(f"region rank must be one of {', '.join(REGION_RANKS)}, got {rank!r}")
        if not 0.0 <= float(threshold) < 1.0:
            raise ConfigError(f"region threshold must be a class probability in [0, 1), got {threshold!r}")
        label = prob.argmax(0)
        wanted = None if obs.target_obj_ids is None else [int(o) for o in obs.target_obj_ids]
        out = []
        for c, oid in enumerate(self.class_ids, start=1):
            limit = None if wanted is None else wanted.count(oid) * int(per_instance)
            if limit == 0:
                continue
            member = label == c if threshold <= 0 else prob[c] > float(threshold)
            n, comp, stats, _ = cv2.connectedComponentsWithStats(member.astype(np.uint8), connectivity=8)
            order = [i for i in np.argsort(-stats[1:, cv2.CC_STAT_AREA], kind="stable") + 1
                     if stats[i, cv2.CC_STAT_AREA] >= self.min_region_pixels]
            masks = [comp == i for i in order]
            found = [(m, float(prob[c][m].mean())) for m in masks]
            if rank == "prob":
                found.sort(key=lambda mp: -mp[1])
            for mask, p in found[:limit]:
                out.append((oid, self._erode(mask), p))
        return out

    def fit_regions(self, icp: ICPEstimator, obs: Observation) -> list[PoseEstimate]:
        """Poses of the objects this network finds in ``obs``, each region fitted by ``icp``
        (:meth:`~simtest.estimators.icp.ICPEstimator.fit_mask`); an estimate's score is the ICP fitness times the
        region's mean class probability. Objects asked for that the network does not know are reported in
        ``icp.last_failures``.

        Raises:
            ConfigError: The observation's object set is not the one the network was trained for.
        """
        self.check_objects(obs.objects)
        rng = obs.rng(icp.seed)
        for oid in sorted(set(obs.target_obj_ids or ()) - set(self.class_ids)):
            icp.last_failures.append({"obj_id": int(oid), "target_index": None,
                                      "reason": f"object {oid} is not one the segmentation network was trained "
                                                f"for ({', '.join(map(str, self.class_ids))})"})
        out = []
        for oid, mask, p in self.regions(obs):
            est = icp.fit_mask(obs, oid, mask, None, rng)
            if est is not None:
                out.append(replace(est, score=float(est.score * p),
                                   info={**est.info, "region_pixels": int(mask.sum()), "region_prob": p}))
        return out


def estimate_segmented(icp: ICPEstimator, obs: Observation) -> list[PoseEstimate]:
    """Poses of the objects ``icp.segmenter`` finds in ``obs``, fitted by ``icp`` (:meth:`Segmenter.fit_regions`).

    Raises:
        ConfigError: The observation's object set is not the one the network was trained for.
    """
    return icp.segmenter.fit_regions(icp, obs)


class SegICPEstimator(ICPEstimator):
    """``segicp``: a learned segmentation finds the objects in RGB, depth gives their pose (coarse rotation
    search + ICP). Reads no ground truth (``needs_gt_masks = False``).

    Args:
        checkpoint: Segmentation checkpoint from ``simtest train segmentation`` (default: the shipped one for
            ``builtin-small``; other object sets need their own).
        device, min_region_pixels, threads, erode_px, flip, runtime: See :class:`Segmenter`.
        coarse_rotations, refine_top, max_iterations, min_fitness, seed: See
            :class:`~simtest.estimators.icp.ICPEstimator`.
    """

    needs_gt_masks = False
    #: The object set of the shipped checkpoint (``simtest grasp`` uses it unless told ``--objects``).
    default_object_set = "builtin-small"

    def __init__(self, checkpoint: str | None = None, device: str = "cpu", min_region_pixels: int = 40,
                 threads: int | None = None, erode_px: int = 0, flip: bool = True, coarse_rotations: int = 600,
                 refine_top: int = 4, max_iterations: int = 30, min_fitness: float = 0.5, seed: int = 0,
                 runtime: str = "auto") -> None:
        super().__init__(max_iterations=max_iterations, coarse_rotations=coarse_rotations, refine_top=refine_top,
                         min_fitness=min_fitness, seed=seed)
        self.masks = "segicp"
        self.needs_gt_masks = False
        if int(erode_px) < 0:
            raise ConfigError(f"segicp: erode_px must be >= 0 pixels, got {erode_px!r}")
        self.segmenter = Segmenter(checkpoint, device, min_region_pixels, threads, int(erode_px), flip, runtime)

    def __repr__(self) -> str:
        return f"SegICPEstimator(checkpoint={self.segmenter.checkpoint!r}, runtime={self.segmenter.runtime!r})"
