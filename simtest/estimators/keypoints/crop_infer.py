"""The keypoint estimator (``keypoints``): detect, zoom in, predict keypoints with confidences, fuse, PnP. RGB only.

1. Detection, one box per object found: ``detect="rgb"`` (default) by the shipped RGB-only segmentation network
   of this estimator (``weights/keypoints_detector_builtin-small_320x240.onnx``, trained by ``simtest train
   segmentation`` without ``--depth-input``), ``detect="segicp"`` by segicp's shipped RGB-D network (depth then
   serves the detection only), ``detect="gt"`` from the targets' ground-truth visible boxes (the estimator then
   declares ``needs_gt_masks``: its runs are labelled ``(GT masks)``). Boxes are the bounding boxes of the
   connected regions of each class (:meth:`simtest.estimators.segicp.infer.Segmenter.regions`).
2. Per detection a square window ``margin`` times the box's longer side, resampled to ``crop_size`` pixels,
   with intrinsics ``K' = M K`` (:func:`~simtest.estimators.keypoints.crops.crop_intrinsics`). With ``recrop``
   (default 2) the crop is framed again from the box of the network's own object cells in it, as the
   ground-truth visible boxes frame the training crops, and the network run on the new crop (not with
   ``detect=gt``, whose boxes are those).
3. The crop network (:mod:`.crop_model`) gives, for the detection's class, per cell an object-mask probability,
   keypoint offsets and confidences ``c = softplus(z)``.
4. On the cells with mask probability >= ``fg_threshold``, per keypoint the ``top_n`` most confident
   predictions are averaged with their confidences as weights (``fusion="confidence"``, :func:`fuse_keypoints`),
   or all of them with equal weights (``fusion="uniform"``).
5. The fused keypoints go back to the full image (``M^-1``) and PnP with the full ``K`` gives the pose
   (:func:`~simtest.estimators.keypoints.infer.solve_pnp`: EPnP + LM, SQPnP + LM or RANSAC).
6. With ``refine="silhouette"`` (the default) the pose is fitted to the crop network's own mask
   (:mod:`simtest.estimators.silhouette`): the model's exact silhouette in the crop, compared through the cell
   rule the mask was trained with, is moved in depth, image position and (``refine_deg`` first steps) rotation
   to maximise its soft IoU with the mask probability, over the crop pixels inside the image and outside the
   other detections' masks. PnP on correspondences blurred toward the object's middle leaves the depth a few
   percent off; the outline pins it. ``refine_coverage`` (0.2) is the cell coverage at which the network's
   mask probability crosses 0.5: calibrated on a held-out set (seed 108; median depth ratio 1.001 there; the
   training rule's 0.3 leaves the fitted silhouettes 1 % too near). Still RGB only.

A network with the object-coordinate head (``dense`` in its config; ``simtest train keypoints`` trains it by
default) predicts per object cell the model-frame 3D point it sees and a confidence; with ``solver="dense"``
(the default for such a network) those cells are the 2D-3D correspondences instead of the 8 fused keypoints:
the cell centres mapped to the full image against their predicted points, the ``dense_keep`` most confident
fraction of them (``fusion="confidence"``) or all (``fusion="uniform"``, what ``fusion="auto"`` picks for the
dense solver: 24.4 against 19.7 % ADD(-S)-0.1d on the validation set of docs/training.md), solved by RANSAC EPnP (threshold
``ransac_px`` full-image pixels) and LM on the inliers. Hundreds of correspondences average out the error of
each one, which 8 keypoints cannot.

With ``pose=templates`` steps 2-6 are replaced by template matching
(:class:`~simtest.estimators.templates.estimator.TemplateEstimator`, sharing the detector): the pose stage the
shipped LM-O set takes by default (:func:`simtest.estimators.shipped.pose_stage`; docs/sim2real.md). Where
several shipped detectors know the objects (LM-O: two), template matching pools their regions; the crop
network's pose stage reads the first.

The observation's depth is never read (``detect="segicp"`` excepted, for the detection). torch is imported only
for a ``.pt`` checkpoint without its current ONNX file (or ``runtime=torch``).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np

from simtest.camera import pinhole_pixels
from simtest.errors import ConfigError
from simtest.estimators.base import Observation, PoseEstimate
from simtest.estimators.checkpoint import check_objects
from simtest.estimators.keypoints.checkpoint import load_checkpoint
from simtest.estimators.onnx_net import OnnxNet, check_device, resolve_runtime, softplus
from simtest.estimators.segicp.infer import FORMAT as SEG_FORMAT
from simtest.estimators.segicp.infer import REGION_RANKS, Segmenter
from simtest.estimators.silhouette import fit_translation
from simtest.io.bop import mask_bbox
from simtest.estimators.keypoints.crops import crop_intrinsics, crop_window_for_box, map_pixels, warp_crop
from simtest.estimators.keypoints.infer import PNP_METHODS, fuse_keypoints, solve_pnp
from simtest.estimators.shipped import choose, choose_all, matches, pose_stage
from simtest.estimators.keypoints.template_stage import (TEMPLATE_CANDIDATES, TEMPLATE_OUTLINE_MASK,  # noqa: F401
                                                         TEMPLATE_OUTLINE_TEMPERATURE, TemplatePoseStage)

if TYPE_CHECKING:
    from simtest.estimators.templates.estimator import TemplateEstimator

__all__ = ["CropKeypointEstimator", "CROP_FORMAT", "DETECTORS", "FUSIONS", "default_checkpoint",
           "default_detector", "crop_maps"]

#: ``format`` of crop-network checkpoints.
CROP_FORMAT = "simtest-keypoints/2"
DETECTORS = ("rgb", "segicp", "gt")
FUSIONS = ("auto", "confidence", "uniform")
SOLVERS = ("auto", "dense", "keypoints")
REFINES = ("none", "silhouette")
#: The pose stages: the crop network, or template matching on the same detections (:data:`POSE_STAGES`).
POSES = ("network", "templates")
CHECKPOINT_NAME = "keypoints_builtin-small_320x240.pt"
DETECTOR_NAME = "keypoints_detector_builtin-small_320x240.pt"


def _weights() -> Path:
    return Path(__file__).resolve().parent.parent / "weights"


def default_checkpoint() -> Path:
    """The shipped crop-network checkpoint (``builtin-small``, 320x240 training images; its ONNX file beside)."""
    return _weights() / CHECKPOINT_NAME


def default_detector() -> Path:
    """The shipped RGB-only segmentation checkpoint used for detection (its ONNX file beside it)."""
    return _weights() / DETECTOR_NAME


def crop_maps(fg: np.ndarray, kp: np.ndarray, label: int, cfg: dict[str, Any], xyz: np.ndarray | None = None
              ) -> dict[str, np.ndarray]:
    """One crop's maps for class ``label`` (1..C) from the raw outputs ``fg`` (C, h, w) and ``kp`` (C 3 J, h, w):
    ``prob`` (h, w) mask probability, ``points`` (J, 2, h, w) keypoints in crop pixels, ``conf`` (J, h, w),
    ``centers`` (2, h, w) the cells' centres (crop pixels); with ``xyz`` (4 H C, h, w) also ``xyz``
    (H, 3, h, w) model-frame points (metres) and ``xyz_conf`` (H, h, w) of the ``H`` hypotheses."""
    J, stride = int(cfg["num_keypoints"]), int(cfg.get("stride", 4))
    h, w = fg.shape[-2:]
    c = int(label) - 1
    k = kp.reshape(-1, 3 * J, h, w)[c].astype(np.float64)
    gx = np.arange(w) * stride + (stride - 1) / 2.0
    gy = np.arange(h) * stride + (stride - 1) / 2.0
    centers = np.stack(np.meshgrid(gx, gy, indexing="xy"))  # (2, h, w): x, y
    points = k[:2 * J].reshape(J, 2, h, w) * float(cfg["offset_scale"]) + centers[None]
    out = {"prob": 1.0 / (1.0 + np.exp(-fg[c].astype(np.float64))), "points": points,
           "conf": softplus(k[2 * J:]), "centers": centers}
    if xyz is not None:
        d = xyz.reshape(-1, int(cfg.get("hypotheses", 1)), 4, h, w)[c].astype(np.float64)
        out["xyz"] = d[:, :3] * float(cfg["xyz_scale"][c])
        out["xyz_conf"] = softplus(d[:, 3])
    return out


class CropKeypointEstimator(TemplatePoseStage):
    """Zoom-in keypoint pose estimator (registered as ``keypoints``); see the module doc.

    Args:
        checkpoint: Crop-network checkpoint from ``simtest train keypoints`` (``.pt`` or its ``.onnx``); None:
            the shipped one (``builtin-small``).
        detect: ``rgb``, ``segicp`` or ``gt`` (see the module doc).
        detector: Segmentation checkpoint for ``detect=rgb`` (None: the shipped RGB-only ones), or several
            joined by ``+`` (``A.onnx+B.onnx``): ``pose=templates`` pools their regions, the crop network
            reads the first's.
        fusion: ``auto`` (``confidence`` for the keypoint solver, ``uniform`` for the dense one), ``confidence``
            (top ``top_n`` per keypoint, confidence-weighted) or ``uniform`` (all object cells,
            equal weights).
        top_n, min_conf: Fused predictions per keypoint and their confidence floor (:func:`fuse_keypoints`).
        pnp: ``epnp``, ``sqpnp`` or ``ransac`` (:func:`solve_pnp`).
        fg_threshold: Mask probability from which a cell votes (if fewer than 4 cells pass, the 8 most probable).
        min_region_pixels: Smallest detected region (pixels).
        device: ``cpu`` or ``cuda`` (torch runtime only). threads: CPU threads (None: 1 for ONNX Runtime).
        runtime: ``auto``, ``onnx`` or ``torch`` (:func:`simtest.estimators.onnx_net.resolve_runtime`).
        solver: ``dense`` (object-coordinate correspondences, needs a dense network), ``keypoints`` (the fused
            keypoints) or ``auto`` (dense when the network has the head).
        dense_keep: ``solver=dense`` with ``fusion=confidence``: the fraction of object cells kept, most
            confident first (at least 8). ransac_px: its RANSAC threshold, full-image pixels.
        refine: ``silhouette`` (default) or ``none``/None: the silhouette fit of step 6 of the module doc.
        refine_deg: Its first rotation step in degrees (0: translation only); refine_max_scale: the largest
            relative depth change it may make; refine_coverage: the cell coverage at which the mask network's
            probability is taken to cross 0.5 (see the module doc).
        recrop: Passes that frame each crop anew from the crop network's own object cells of the pass before
            (0-3): the detector's box starts it, then the box of the cells with mask probability
            >= ``fg_threshold`` mapped back to the full image. None (default): 2 with a detector (chosen on the
            validation set of docs/training.md: 24.4, 26.4, 28.0, 26.4 % ADD(-S)-0.1d for 0-3 passes), 0 with
            ``detect=gt`` (the ground-truth visible box already frames the crop as in training).
        candidates: With a detector and the target ids given (localization): up to this many of the
            detector's regions (ranked by ``region_rank``) per expected instance get a pose, and per object the
            best-scored poses, as many as it has instances, are kept (1: the first region only). For
            clutter a detector trained on renders mistakes for an object. None: 1, or
            :data:`TEMPLATE_CANDIDATES` with ``pose=templates``.
        pose: ``network`` (the crop network, steps 2-6 of the module doc) or ``templates`` (the detections
            posed by :class:`~simtest.estimators.templates.estimator.TemplateEstimator`: templates rendered
            from the models, no training; the best template match among the candidates is kept, and with
            ``detect=rgb`` not fitted to the detector's coarse region). None: what
            the shipped set found for the objects prefers (:func:`simtest.estimators.shipped.pose_stage`:
            ``templates`` for LM-O), else ``network``.
        outline: ``pose=templates`` with ``detect=rgb``: the outline network that fits each kept pose to the
            object's visible mask (:mod:`simtest.estimators.templates.outline`); None: the shipped one trained
            for the objects, if any (LM-O's); False (``--opt outline=false``): no outline fit. outline_mask /
            outline_temperature: how that fit reads the network (``soft+flip``) and the divisor of its logits (2).
            framing_starts: window factors the framing search starts from; region_extra: the class probability
            above which more candidate regions are taken; occluders: whether other objects' regions are left
            out of the template scores (None: the stage's, all three; :mod:`.template_stage`).
        region_rank: The order of a class's detector regions: ``prob`` (default: highest mean class probability
            first) or ``area`` (largest first). Chosen on the real LM-O frames (docs/sim2real.md): the detector's
            region holds the object for 44.9 % of 761 real targets ranked by probability, 36.4 % by area; on
            held-out renders the two are equal (67.1 / 67.6 % LM-O, 66.7 / 66.7 % builtin-small).

    Raises:
        ConfigError: Bad options, a missing or unreadable checkpoint; at :meth:`estimate`, an object set other
            than the checkpoint's.
    """

    #: The object set of the shipped checkpoint.
    default_object_set = "builtin-small"

    def __init__(self, checkpoint: str | Path | None = None, detect: str = "rgb", detector: str | None = None,
                 fusion: str = "auto", top_n: int = 16, min_conf: float = 0.0, pnp: str = "epnp",
                 fg_threshold: float = 0.5, min_region_pixels: int = 40, device: str = "cpu",
                 threads: int | None = None, runtime: str = "auto", solver: str = "auto",
                 dense_keep: float = 0.5, ransac_px: float = 3.0, recrop: int | None = None,
                 refine: str | None = "silhouette", refine_deg: float = 2.0, refine_max_scale: float = 0.15,
                 refine_coverage: float = 0.2, candidates: int | None = None, region_rank: str = "prob",
                 pose: str | None = None, outline: str | bool | None = None,
                 outline_mask: str = TEMPLATE_OUTLINE_MASK,
                 outline_temperature: float = TEMPLATE_OUTLINE_TEMPERATURE,
                 framing_starts: tuple[float, ...] | None = None, region_extra: float | None = None,
                 occluders: bool | None = None, *,
                 model: Any = None,
                 objects_record: dict[str, Any] | None = None) -> None:
        from simtest.estimators.templates.estimator import check_framing_starts  # local: import cycle
        from simtest.estimators.templates.outline import MASK_MODES, check_temperature

        for name, val, ok in (("detect", detect, DETECTORS), ("fusion", fusion, FUSIONS), ("pnp", pnp, PNP_METHODS),
                              ("solver", solver, SOLVERS), ("outline_mask", outline_mask, MASK_MODES)):
            if val not in ok:
                raise ConfigError(f"keypoints: unknown {name} {val!r}; valid: {', '.join(ok)}")
        check_temperature(outline_temperature, "keypoints: outline_temperature")
        if framing_starts is not None:
            framing_starts = check_framing_starts(framing_starts, "keypoints: framing_starts")
        if region_extra is not None and not 0.0 <= float(region_extra) < 1.0:
            raise ConfigError(f"keypoints: region_extra must be a class probability in [0, 1), got {region_extra!r}")
        if occluders is not None and not isinstance(occluders, bool):
            raise ConfigError(f"keypoints: occluders must be true or false, got {occluders!r}")
        if int(top_n) < 1:
            raise ConfigError(f"keypoints: top_n must be >= 1, got {top_n!r}")
        if candidates is not None and not (isinstance(candidates, int) and not isinstance(candidates, bool)
                                           and 1 <= candidates <= 8):
            raise ConfigError(f"keypoints: candidates must be an integer 1-8, got {candidates!r}")
        #: Detector regions tried per expected instance; the best-scored poses are kept (localization).
        self.candidates = 1 if candidates is None else int(candidates)
        if pose is not None and (pose not in POSES or (pose == "templates" and detect == "segicp")):
            raise ConfigError(f"keypoints: unknown pose {pose!r} for detect={detect!r}; valid: "
                              f"{', '.join(POSES)} (templates with detect=rgb or gt)")
        #: The pose stage (``network`` or ``templates``); without a ``pose`` option the shipped set decides.
        self.pose = pose or "network"
        self.templates: TemplateEstimator | None = None
        if region_rank not in REGION_RANKS:
            raise ConfigError(f"keypoints: region_rank must be one of {', '.join(REGION_RANKS)}, got {region_rank!r}")
        #: Which detector regions of a class are posed first: ``prob`` (most certain) or ``area`` (largest).
        self.region_rank = region_rank
        if not 0.0 < float(dense_keep) <= 1.0 or not float(ransac_px) > 0.0:
            raise ConfigError(f"keypoints: need 0 < dense_keep <= 1 and ransac_px > 0, got {dense_keep!r}, "
                              f"{ransac_px!r}")
        if recrop is None:
            recrop = 0 if detect == "gt" else 2
        if not (isinstance(recrop, int) and not isinstance(recrop, bool) and 0 <= recrop <= 3):
            raise ConfigError(f"keypoints: recrop must be an integer 0-3 or none, got {recrop!r}")
        refine = "none" if refine is None else refine
        if refine not in REFINES:
            raise ConfigError(f"keypoints: unknown refine {refine!r}; valid: {', '.join(REFINES)}")
        if not (0.0 < float(refine_max_scale) < 1.0 and float(refine_deg) >= 0.0 and 0.0 < float(refine_coverage) < 1.0):
            raise ConfigError(f"keypoints: need 0 < refine_max_scale < 1, refine_deg >= 0 and 0 < refine_coverage < 1, "
                              f"got {refine_max_scale!r}, {refine_deg!r}, {refine_coverage!r}")
        self.refine, self.refine_deg = refine, float(refine_deg)
        self.refine_max_scale, self.refine_coverage = float(refine_max_scale), float(refine_coverage)
        self.dense_keep, self.ransac_px, self.recrop = float(dense_keep), float(ransac_px), int(recrop)
        check_device(device, "keypoints")
        self.detect, self.fusion, self.pnp = detect, fusion, pnp
        self.top_n, self.min_conf, self.fg_threshold = int(top_n), float(min_conf), float(fg_threshold)
        self.device = device
        #: Ground-truth boxes are given (and runs labelled ``(GT masks)``) only with ``detect=gt``.
        self.needs_gt_masks = detect == "gt"
        #: Depth is read only by segicp's RGB-D detector (``detect="segicp"``).
        self.needs_depth = detect == "segicp"
        self.net = self.model = None
        self._options = {"solver": solver, "fusion": fusion, "detector": detector, "runtime": runtime,
                         "threads": threads, "min_region_pixels": int(min_region_pixels), "pose": pose,
                         "candidates": candidates, "outline": outline, "outline_mask": outline_mask,
                         "outline_temperature": float(outline_temperature), "framing_starts": framing_starts,
                         "region_extra": region_extra, "occluders": occluders}
        #: No checkpoint given: the shipped network whose objects match is taken (:meth:`check_objects`).
        self.shipped = checkpoint is None and model is None
        if model is not None:
            if objects_record is None:
                raise ConfigError("keypoints: a model given in memory needs its objects_record")
            self.model, self.runtime, self.checkpoint = model.to(device).eval(), "torch", None
            self.cfg, self.record = model.cfg.to_dict(), objects_record
        else:
            self._load(checkpoint, runtime, threads)
        self._configure()
        self.segmenter = None
        self.more_segmenters: list = []
        if detect != "gt":
            first, *more = [None] if detect == "segicp" else str(detector or default_detector()).split("+")
            self._load_detector(first, [Path(m) for m in more])
        self.last_failures: list[dict[str, Any]] = []
        self._checked: set[int] = set()

    def _configure(self) -> None:
        """Settings that follow from the loaded network: keypoints, solver, fusion, classes."""
        self.kp3d = {int(i): np.asarray(k, np.float64) for i, k in zip(self.record["obj_ids"], self.record["keypoints"])}
        solver, fusion = self._options["solver"], self._options["fusion"]
        has_dense = bool(self.cfg.get("dense", False))
        if solver == "dense" and not has_dense:
            raise ConfigError(f"keypoints: solver=dense needs a network with the object-coordinate head; "
                              f"{self.checkpoint or '(in memory)'} has none (use solver=keypoints)")
        self.solver = ("dense" if has_dense else "keypoints") if solver == "auto" else solver
        self.fusion = ("uniform" if self.solver == "dense" else "confidence") if fusion == "auto" else fusion
        self.class_ids = [int(i) for i in self.record["obj_ids"]]

    def _load_detector(self, path: str | Path | None, more: list[Path] | None = None) -> None:
        """The segmentation network that finds the objects (None: segicp's shipped RGB-D one) and ``more``
        detectors whose regions ``pose=templates`` pools with its own (``self.more_segmenters``)."""
        if self.detect == "rgb" and self._options["detector"] is None and not Path(path).is_file():
            raise ConfigError(f"keypoints: the shipped detector {str(path)!r} is missing; pass "
                              "--opt detector=SEGMENTATION_CHECKPOINT or --opt detect=gt")
        self.segmenter, *self.more_segmenters = [
            Segmenter(p, "cpu", self._options["min_region_pixels"], self._options["threads"], runtime="auto")
            for p in [path, *(more or [])]]
        if self.detect == "rgb" and self.segmenter.depth_input:
            raise ConfigError(f"keypoints: detector {self.segmenter.checkpoint} reads depth; detect=rgb needs an "
                              "RGB-only segmentation network (simtest train segmentation without --depth-input)")

    def _ship_for(self, objects: Any) -> None:
        """Swap in the shipped crop network (and, unless one was named, the shipped detector) trained for
        ``objects``; a :class:`ConfigError` names the shipped sets when none was."""
        net = choose("keypoints", CROP_FORMAT, objects, what="keypoints")
        if self._options["pose"] is None and self.detect != "segicp":
            self.pose = pose_stage(net)
        self._load(net.path, self._options["runtime"], self._options["threads"])
        self._configure()
        if self.detect == "rgb" and self._options["detector"] is None:
            det, *more = choose_all("keypoints_detector", SEG_FORMAT, objects, what="keypoints (its detector)",
                                    subset=True)
            self._load_detector(det.path, [m.path for m in more])

    def _load(self, checkpoint: str | Path | None, runtime: str, threads: int | None) -> None:
        shipped = checkpoint is None
        path = default_checkpoint() if shipped else Path(checkpoint)
        if shipped and not path.is_file():
            raise ConfigError(f"keypoints: the shipped checkpoint {str(path)!r} is missing; train one with "
                              "`simtest train keypoints` and pass --opt checkpoint=PATH")
        self.runtime, path = resolve_runtime(path, runtime, "keypoints")
        self.checkpoint = str(path)
        if self.runtime == "onnx":
            if self.device != "cpu":
                raise ConfigError(f"keypoints: the ONNX runtime runs on the CPU; device={self.device!r} needs "
                                  "runtime=torch and a .pt checkpoint")
            self.net = OnnxNet(path, CROP_FORMAT, threads)
            self.cfg, self.record = self.net.meta["net"], self.net.meta["objects"]
            return
        import torch

        from simtest.estimators.keypoints.crop_model import CropKeypointNet, CropNetConfig

        if threads is not None:
            torch.set_num_threads(int(threads))
        ckpt = load_checkpoint(path, fmt=CROP_FORMAT)
        net = CropKeypointNet(CropNetConfig.from_dict(ckpt["net"]))
        net.load_state_dict(ckpt["model"])
        self.model, self.cfg, self.record = net.to(self.device).eval(), dict(ckpt["net"]), ckpt["objects"]

    def __repr__(self) -> str:
        return (f"CropKeypointEstimator(checkpoint={self.checkpoint!r}, detect={self.detect!r}, "
                f"fusion={self.fusion!r}, solver={self.solver!r}, refine={self.refine!r}, runtime={self.runtime!r})")

    def check_objects(self, objects: Any) -> None:
        """Raise :class:`ConfigError` unless ``objects`` is the set the network was trained for."""
        if id(objects) not in self._checked:
            if self.shipped and matches(self.record, objects) is not None:
                self._ship_for(objects)
            check_objects(self.record, objects, where=f"keypoints checkpoint {self.checkpoint or '(in memory)'}")
            if self.segmenter is not None:
                self.segmenter.check_objects(objects)
            self._checked.add(id(objects))

    def _run(self, x: np.ndarray) -> dict[str, np.ndarray]:
        """The network's outputs by name (``fg``, ``kp`` and, for a dense network, ``xyz``)."""
        if self.net is not None:
            return dict(zip(self.net.output_names, self.net.run(x)))
        import torch

        with torch.inference_mode():
            out = self.model(torch.from_numpy(x).to(self.device))
        return {k: v.cpu().numpy() for k, v in out.items()}

    def detections(self, obs: Observation) -> list[tuple[int | None, int, np.ndarray, float, np.ndarray]]:
        """``(target index or None, obj_id, box [x, y, w, h], detection score, mask (H, W) bool)`` per object
        found."""
        out = []
        if self.detect == "gt":
            obs.require_targets("keypoints (detect=gt)")
            for k, (oid, m) in enumerate(zip(obs.target_obj_ids, obs.masks)):
                m = np.asarray(m, bool)
                if m.any():
                    out.append((k, int(oid), np.asarray(mask_bbox(m), np.float64), 1.0, m))
                else:
                    self.last_failures.append({"obj_id": int(oid), "reason": "empty ground-truth mask"})
            return out
        seen = obs if self.detect == "segicp" else replace(obs, depth=np.zeros(obs.rgb.shape[:2], np.float32))
        for oid, mask, p in self.segmenter.regions(seen, self.candidates, self.region_rank):
            out.append((None, int(oid), np.asarray(mask_bbox(mask), np.float64), float(p), np.asarray(mask, bool)))
        return out

    def estimate(self, observation: Observation) -> list[PoseEstimate]:
        """Pose estimates (metres, camera frame) of the detected objects (see the module doc)."""
        obs = observation
        self.check_objects(obs.objects)
        self.last_failures = []
        if self.pose == "templates":
            return self._template_poses(obs)
        dets = [d for d in self.detections(obs) if self._known(d[1])]
        if not dets:
            return []
        K = np.asarray(obs.K, np.float64)
        rgb = np.asarray(obs.rgb, np.float32) / np.float32(255.0)
        boxes, oids = [d[2] for d in dets], [d[1] for d in dets]
        crops = self._crops(rgb, K, boxes, oids)
        for _ in range(self.recrop):
            boxes = [self._mask_box(maps, M, box) for (maps, M), box in zip(crops, boxes)]
            crops = self._crops(rgb, K, boxes, oids)
        out = []
        for n, ((maps, M), (k, oid, box, dscore, _)) in enumerate(zip(crops, dets)):
            try:
                R, t, score, info = self._pose(maps, M, oid, K)
            except (ValueError, cv2.error) as exc:
                self.last_failures.append({"obj_id": oid, "reason": f"PnP failed: {exc}"})
                continue
            if self.refine == "silhouette":
                others = [d[4] for j, d in enumerate(dets) if j != n]
                R, t, info["silhouette"] = self._refine(obs.objects.get(oid), R, t, maps, M, K, rgb.shape[:2], others)
            info["box"] = [float(v) for v in box]
            out.append(PoseEstimate(obj_id=oid, R=R, t=t, score=float(score * dscore), target_index=k, info=info))
        return self._best_per_target(out, obs)

    def _best_per_target(self, found: list[PoseEstimate], obs: Observation) -> list[PoseEstimate]:
        """With ``candidates > 1`` and the target ids known: per object the as many best-scored estimates as
        it has expected instances (the other candidates are dropped)."""
        if self.candidates == 1 or obs.target_obj_ids is None:
            return found
        wanted = [int(o) for o in obs.target_obj_ids]
        keep: set[int] = set()
        for oid in {e.obj_id for e in found}:
            mine = sorted((i for i, e in enumerate(found) if e.obj_id == oid), key=lambda i: -found[i].score)
            keep.update(mine[:wanted.count(oid)])
        return [e for i, e in enumerate(found) if i in keep]

    def _crops(self, rgb: np.ndarray, K: np.ndarray, boxes: list[np.ndarray], oids: list[int]
               ) -> list[tuple[dict[str, np.ndarray], np.ndarray]]:
        """Per box (full-image pixels) its crop's maps (:func:`crop_maps`) and crop map ``M``, in one batch."""
        S = int(self.cfg["crop_size"])
        Ms = [crop_intrinsics(K, crop_window_for_box(box, float(self.cfg["margin"])), S)[1] for box in boxes]
        x = np.stack([warp_crop(rgb, M, S).transpose(2, 0, 1) for M in Ms]).astype(np.float32)
        res = self._run(np.ascontiguousarray(x))
        return [(crop_maps(res["fg"][n], res["kp"][n], self.class_ids.index(oid) + 1, self.cfg,
                           res["xyz"][n] if "xyz" in res else None), M) for n, (oid, M) in enumerate(zip(oids, Ms))]

    def _refine(self, obj: Any, R: np.ndarray, t: np.ndarray, maps: dict[str, np.ndarray], M: np.ndarray,
                K: np.ndarray, shape: tuple[int, int], others: list[np.ndarray]
                ) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
        """``refine="silhouette"``: the pose fitted to the crop network's mask probability in the crop
        (:func:`simtest.estimators.silhouette.fit_translation`, through the cell rule at ``refine_coverage``),
        counting the crop pixels inside the image and outside the other detections' masks."""
        S = int(self.cfg["crop_size"])
        prob = cv2.resize(maps["prob"].astype(np.float32), (S, S), interpolation=cv2.INTER_LINEAR)
        valid = warp_crop(np.ones(shape, np.float32), M, S) >= 0.5
        for m in others:
            valid &= ~warp_crop(m, M, S, nearest=True)
        fit = fit_translation(obj, R, t, M @ K, prob, valid, max_scale=self.refine_max_scale,
                              cells=(int(self.cfg.get("stride", 4)), self.refine_coverage), step_deg=self.refine_deg)
        return fit.R, fit.t, {"applied": fit.applied, "iou_before": fit.iou_before, "iou_after": fit.iou_after,
                              "scale": fit.scale, "shift_px": list(fit.shift_px), "t_before": t.tolist(),
                              "evaluations": fit.evaluations}

    def _mask_box(self, maps: dict[str, np.ndarray], M: np.ndarray, box: np.ndarray) -> np.ndarray:
        """``recrop``: the box ``[x, y, w, h]`` (full-image pixels) of the crop network's own object cells (mask
        probability >= ``fg_threshold``), each cell's pixels mapped back through ``M^-1``; ``box`` unchanged
        when fewer than 4 cells pass. The network segments at the crop's zoom, finer than the detector, and
        the next crop is then framed as the ground-truth visible boxes frame the training crops."""
        cells = maps["prob"] >= self.fg_threshold
        if cells.sum() < 4:
            return box
        stride = int(self.cfg.get("stride", 4))
        c = maps["centers"][:, cells]  # (2, n) cell centres, crop pixels
        half = (stride - 1) / 2.0
        lo, hi = map_pixels(np.linalg.inv(M), np.stack([c.min(axis=1) - half, c.max(axis=1) + half]))
        return np.array([lo[0], lo[1], hi[0] - lo[0], hi[1] - lo[1]], np.float64)

    def _known(self, oid: int) -> bool:
        if oid in self.kp3d:
            return True
        self.last_failures.append({"obj_id": oid, "reason": f"object {oid} not in the trained set"})
        return False

    def _pose(self, maps: dict[str, np.ndarray], M: np.ndarray, oid: int, K: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray, float, dict[str, Any]]:
        prob = maps["prob"]
        cells = prob >= self.fg_threshold
        if cells.sum() < 4:
            flat = np.argsort(-prob, axis=None, kind="stable")[:8]
            cells = np.zeros_like(prob, bool)
            cells.flat[flat] = True
        if self.solver == "dense":
            return self._dense_pose(maps, cells, M, K)
        pts = maps["points"][:, :, cells].transpose(2, 0, 1)  # (M, J, 2) crop pixels
        conf = maps["conf"][:, cells].T  # (M, J)
        if self.fusion == "confidence":
            kp, kc = fuse_keypoints(pts, conf, self.top_n, self.min_conf)
        else:
            kp, kc = pts.mean(0), conf.mean(0)
        kp_full = map_pixels(np.linalg.inv(M), kp)
        R, t, rms = solve_pnp(kp_full, self.kp3d[oid], K, self.pnp)
        mc = float(kc.mean())
        return R, t, mc / (1.0 + mc) * float(prob[cells].mean()), {
            "cells": int(cells.sum()), "reproj_rms_px": rms, "keypoints_2d": kp_full.tolist(),
            "keypoint_conf": kc.tolist()}

    def _dense_pose(self, maps: dict[str, np.ndarray], cells: np.ndarray, M: np.ndarray, K: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray, float, dict[str, Any]]:
        """The pose from the object cells' predicted model points (``solver=dense``; see the module doc): per
        hypothesis RANSAC EPnP + LM; the one with the most inliers (then the lowest inlier error) is kept."""
        uv_all = map_pixels(np.linalg.inv(M), maps["centers"][:, cells].T)  # (M, 2) full-image pixels
        best = None
        for h in range(maps["xyz"].shape[0]):
            xyz = maps["xyz"][h][:, cells].T  # (M, 3) metres
            conf = maps["xyz_conf"][h][cells]
            uv = uv_all
            if self.fusion == "confidence" and len(conf) > 8:
                keep = max(8, int(np.ceil(self.dense_keep * len(conf))))
                sel = np.argsort(-conf, kind="stable")[:keep]
                xyz, conf, uv = xyz[sel], conf[sel], uv[sel]
            try:
                R, t, _ = solve_pnp(uv, xyz, K, "ransac", self.ransac_px)
            except (ValueError, cv2.error):
                continue
            pu, pv = pinhole_pixels(K, xyz @ R.T + t)
            err = np.hypot(pu - uv[:, 0], pv - uv[:, 1])
            inl = err <= self.ransac_px
            rank = (int(inl.sum()), -float(np.mean(err[inl])) if inl.any() else -np.inf)
            if best is None or rank > best[0]:
                best = (rank, R, t, h, conf, len(xyz), float(np.sqrt(np.mean(err[inl] ** 2))) if inl.any() else np.inf)
        if best is None:
            raise ValueError("PnP failed for every object-coordinate hypothesis")
        (n_inl, _), R, t, h, conf, n, rms = best
        prob = maps["prob"][cells]
        mc = float(np.mean(conf))
        return R, t, mc / (1.0 + mc) * float(prob.mean()) * n_inl / max(n, 1), {
            "cells": int(cells.sum()), "correspondences": int(n), "inliers": int(n_inl), "hypothesis": int(h),
            "reproj_rms_px": rms}
