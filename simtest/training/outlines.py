"""The trainer of the outline network (``simtest train outlines``): crops of simtest renders around each visible
object, the object's silhouette moved a little as the prior, its visible mask as the target
(:mod:`simtest.estimators.templates.mask_model`), run by the one training loop (:func:`simtest.training.fit.fit`).

A sample is one annotated instance (visible fraction at least ``min_visib``) of a training image. Its crop is
the one the template estimator looks through (:func:`~simtest.estimators.templates.crops.region_crop` of the
amodal mask, margin 1.2, rolled up to +-20 degrees), then shifted by up to +-6 % of the window and scaled by
up to exp(+-0.1), as a searched framing is off. The prior is the amodal mask in that crop moved by a similarity
(+-4 % shift, exp(+-0.05) scale, +-6 degrees), as a found pose is off; the target is the visible mask in the
crop (with ``target = "amodal"``: the whole silhouette in the crop, hidden parts too, so that a pose fitted to
the network's mask is not pulled back where something in front hides the object). With ``pose_priors`` (a
share of the samples) the prior is instead the object's silhouette at its pose turned by up to
:data:`POSE_TURN_DEG` about a random axis, moved along its viewing ray by up to exp(+-0.06) and across it by up
to +-5 % of its diameter, and the crop is framed on that silhouette as
:func:`~simtest.estimators.templates.outline.outline_fit` frames a found pose (rolled as above): a pose that is
off shows another outline, not only a moved one. The crop is then blurred (Gaussian, sigma 0.2-1.8 pixels, 70 %
of samples; with ``camera_scale = "image"`` the image around the object, before cropping, sigma 0.5-1.8 image
pixels, 85 %), its brightness, contrast, saturation and channel gains jittered and Gaussian noise added: real
cameras are blurrier and noisier than renders. Every draw comes from ``SeedSequence(seed, spawn_key=(epoch, index))``, so a resumed run sees the
same samples. Loss: binary cross-entropy plus the soft Dice loss of each crop's mask.

Checkpoints (:func:`~simtest.training.fit.fit`'s run folder)::

    {"format": "simtest-outline/1", "net": MaskNetConfig dict, "objects": object record, "model": state_dict,
     "epoch": int, "optimizer": state_dict | None, "history": [...], "train": settings}

With a validation dataset the mean IoU of the predicted masks (crops drawn the same way with the validation
seed, no photometric changes) is measured after every epoch, beside the prior's own IoU, and its best epoch
kept in ``best.pt``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import cv2
import numpy as np

from simtest.data.augment import ObjectLight
from simtest.errors import ConfigError
from simtest.estimators.checkpoint import check_objects, object_record
from simtest.estimators.templates.crops import mask_in_crop, region_crop, window_crop
from simtest.estimators.templates.outline import FORMAT
from simtest.io import bop
from simtest.io.bop_splits import dataset_split_dir, scene_dirs
from simtest.objects.loaders import load_dataset_objects
from simtest.training.fit import Plan, TrainResult, fit
from simtest.training.segmentation import data_roots
from simtest.training.settings import check_settings, settings_dict

__all__ = ["TARGETS", "check_target", "OutlineTrainConfig", "OutlineCrops", "train_outlines", "outline_sample",
           "pose_sample", "FORMAT"]

#: What an outline network learns to draw (:attr:`OutlineTrainConfig.target`).
TARGETS = ("visible", "amodal")
#: Margin of the crop around the object (the template estimator's, :class:`BankSettings.margin`).
MARGIN = 1.2


@dataclass(frozen=True)
class OutlineTrainConfig:
    """Settings of one outline training run (recorded in the checkpoints).

    Attributes:
        data, split: Training BOP dataset folders (with amodal and visible masks) and their split; out: run folder.
        val, val_split, val_images: Validation dataset (None: none), its split, its first N images only.
        epochs, batch_size, lr, weight_decay: As ``simtest train segmentation``.
        crop_size: Side of the crops (pixels, a multiple of 32).
        min_visib: Smallest visible fraction of an instance that makes a sample.
        max_images: Train on the first N images of each dataset only (None: all).
        device, seed, workers, threads: As ``simtest train segmentation``.
        augment_p: The share of samples given the camera's changes (blur, colour, noise; default all).
        pose_priors: The share of samples whose prior is the silhouette at a perturbed pose (default 0: every
            prior is the moved amodal mask).
        camera_scale: Where the camera's changes apply: ``"crop"`` (to the crop, as the shipped network was
            trained) or ``"image"`` (to the image around the object before it is cropped, blur sigma 0.5-1.8
            image pixels: a camera blurs in its own pixels, so a small object's crop is blurrier).
        image_skip: The network's last stage also reads the crop's pixels (:class:`MaskNetConfig`; default on).
        object_light: The share of samples whose object's visible pixels in the crop are brightened or dimmed
            by a gain of their own (:class:`~simtest.data.augment.ObjectLight`, before the camera's changes;
            default 0: none). Real cameras show objects lit brighter against their surroundings than renders.
        target: What the network learns to draw: ``"visible"`` (the object's visible pixels, as the shipped
            network) or ``"amodal"`` (its whole silhouette, hidden parts too).
        encoder_lr_scale, freeze_encoder_bn: Fixed at 0 and True (the encoder stays frozen); the loop reads them.
    """

    data: str | tuple[str, ...]
    out: str
    split: str | None = None
    val: str | None = None
    val_split: str | None = None
    val_images: int | None = None
    epochs: int = 3
    batch_size: int = 32
    lr: float = 2e-3
    weight_decay: float = 1e-4
    crop_size: int = 128
    min_visib: float = 0.15
    max_images: int | None = None
    device: str = "cpu"
    seed: int = 0
    workers: int = 0
    threads: int | None = None
    augment_p: float = 1.0
    pose_priors: float = 0.0
    camera_scale: str = "crop"
    image_skip: bool = True
    object_light: float = 0.0
    target: str = "visible"
    encoder_lr_scale: float = 0.0
    freeze_encoder_bn: bool = True

    def __post_init__(self) -> None:
        check_settings(self, "outline training")
        if int(self.crop_size) < 32 or int(self.crop_size) % 32:
            raise ConfigError(f"outline training: crop_size must be a positive multiple of 32, got {self.crop_size!r}")
        if self.camera_scale not in _BLUR:
            raise ConfigError(f"outline training: camera_scale must be one of {', '.join(_BLUR)}, got "
                              f"{self.camera_scale!r}")
        check_target(self.target, self.object_light)
        if not 0.0 <= float(self.pose_priors) <= 1.0:
            raise ConfigError(f"outline training: pose_priors must be a share in [0, 1], got {self.pose_priors!r}")
        if not 0.0 <= float(self.object_light) <= 1.0:
            raise ConfigError(f"outline training: object_light must be a share in [0, 1], got {self.object_light!r}")
        if not 0.0 <= float(self.min_visib) < 1.0:
            raise ConfigError(f"outline training: min_visib must be in [0, 1), got {self.min_visib!r}")
        if self.encoder_lr_scale != 0.0 or not self.freeze_encoder_bn:
            raise ConfigError("outline training: the encoder stays frozen (encoder_lr_scale 0, freeze_encoder_bn)")

    def to_dict(self) -> dict[str, Any]:
        return settings_dict(self)


def check_target(target: str, object_light: float = 0.0) -> str:
    """``target`` if it is one of :data:`TARGETS` and goes with ``object_light`` (which brightens the visible
    pixels, so only with ``"visible"``).

    Raises:
        ConfigError: Another target, or ``"amodal"`` with ``object_light`` > 0 (naming the values).
    """
    if target not in TARGETS:
        raise ConfigError(f"outline training: target must be one of {', '.join(TARGETS)}, got {target!r}")
    if target == "amodal" and float(object_light) > 0:
        raise ConfigError("outline training: object_light brightens the object's visible pixels, which an amodal "
                          f"sample does not carry; use it with target 'visible' (got object_light {object_light!r})")
    return target


def _instances(roots: list[str], split: str | None, min_visib: float, max_images: int | None
               ) -> list[tuple[str, int, int]]:
    """``(scene folder, im_id, gt_id)`` of every instance visible enough, dataset by dataset, in file order."""
    out = []
    for root in roots:
        images = 0
        for scene in scene_dirs(dataset_split_dir(root, split)):
            for im, d in sorted(bop.read_scene(scene).items()):
                if max_images is not None and images >= max_images:
                    break
                images += 1
                out += [(str(scene), im, g) for g, gt in enumerate(d["gt"]) if gt.visib_fract >= min_visib]
    return out


#: Blur of the camera's changes: (share of samples, sigma range in pixels) at the crop's scale and, with
#: ``camera_scale = "image"``, at the image's.
_BLUR = {"crop": (0.7, (0.2, 1.8)), "image": (0.85, (0.5, 1.8))}


def _photometric(rgb: np.ndarray, rng: np.random.Generator, scale: str = "crop") -> np.ndarray:
    """Blur, brightness, contrast, saturation, channel gains and noise (see the module doc), uint8."""
    x = rgb.astype(np.float32)
    share, sigma = _BLUR[scale]
    if rng.random() < share:
        x = cv2.GaussianBlur(x, (0, 0), float(rng.uniform(*sigma)))
    x = x * rng.uniform(0.6, 1.4) + rng.uniform(-30, 30)
    grey = x.mean(2, keepdims=True)
    x = grey + (x - grey) * rng.uniform(0.5, 1.5)
    x = x * rng.uniform(0.85, 1.15, 3)
    x = x + rng.normal(0.0, rng.uniform(0.0, 6.0), x.shape)
    return np.clip(np.rint(x), 0, 255).astype(np.uint8)


def outline_sample(rgb: np.ndarray, K: np.ndarray, amodal: np.ndarray, visible: np.ndarray, size: int,
                   rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One sample of an instance (see the module doc): the crop (S, S, 3) uint8, the prior (S, S) uint8 in {0, 1}
    and the visible mask (S, S) uint8 in {0, 1}; no photometric change."""
    c0 = region_crop(rgb, amodal, K, size, MARGIN, float(np.radians(rng.uniform(-20.0, 20.0))))
    x0, y0, side, _ = c0.window
    s = side * float(np.exp(rng.uniform(-0.1, 0.1)))
    x = x0 + 0.5 * (side - s) + rng.uniform(-0.06, 0.06) * side
    y = y0 + 0.5 * (side - s) + rng.uniform(-0.06, 0.06) * side
    crop = window_crop(rgb, K, c0.R_virt, (x, y, s, s), size, visible)
    full = mask_in_crop(amodal, K, crop)
    M = cv2.getRotationMatrix2D((size / 2, size / 2), float(rng.uniform(-6.0, 6.0)),
                                float(np.exp(rng.uniform(-0.05, 0.05))))
    M[:, 2] += rng.uniform(-0.04, 0.04, 2) * size
    prior = cv2.warpAffine(full.astype(np.uint8), M, (size, size), flags=cv2.INTER_NEAREST)
    return crop.rgb, prior, crop.mask.astype(np.uint8)


#: Largest turn (degrees) of a pose prior's rotation, about a random axis.
POSE_TURN_DEG = 12.0


def pose_sample(rgb: np.ndarray, K: np.ndarray, obj, R: np.ndarray, t: np.ndarray, visible: np.ndarray, size: int,
                rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """One sample whose prior is ``obj``'s silhouette at its pose ``(R, t)`` (model to camera, metres) perturbed
    (see the module doc): the crop (S, S, 3) uint8 framed on that silhouette, the prior and the visible mask
    (S, S) uint8 in {0, 1}; None when the perturbed silhouette leaves the image."""
    from simtest.render.silhouette import object_silhouette

    axis = rng.normal(size=3)
    turn = axis / np.linalg.norm(axis) * np.radians(rng.uniform(0.0, POSE_TURN_DEG))
    R2 = np.asarray(R, np.float64) @ cv2.Rodrigues(turn)[0]
    t2 = np.asarray(t, np.float64).reshape(3) * float(np.exp(rng.uniform(-0.06, 0.06)))
    t2[:2] += rng.uniform(-0.05, 0.05, 2) * float(obj.diameter)
    roll = float(np.radians(rng.uniform(-20.0, 20.0)))
    H, W = rgb.shape[:2]
    sil = object_silhouette(obj, R2, t2, K, W, H) if t2[2] > 0.05 else None
    if sil is None or int(sil.sum()) < 50:
        return None
    crop = region_crop(rgb, sil, K, size, MARGIN, roll)
    return crop.rgb, crop.mask.astype(np.uint8), mask_in_crop(visible, K, crop).astype(np.uint8)


def _around(box, K: np.ndarray, *images: np.ndarray) -> tuple[list[np.ndarray], np.ndarray]:
    """``images`` cut to a window twice the object's box ``[x, y, w, h]`` (pixels) around its centre (at least
    64 pixels more a side; clipped to the image), and the intrinsics of that window."""
    x, y, w, h = (float(v) for v in box)
    half = max(w, h) + 32.0
    H, W = images[0].shape[:2]
    x0, y0 = int(max(0, np.floor(x + w / 2 - half))), int(max(0, np.floor(y + h / 2 - half)))
    x1, y1 = int(min(W, np.ceil(x + w / 2 + half))), int(min(H, np.ceil(y + h / 2 + half)))
    K2 = np.array(K, np.float64)
    K2[0, 2] -= x0
    K2[1, 2] -= y0
    return [np.ascontiguousarray(im[y0:y1, x0:x1]) for im in images], K2


class OutlineCrops:
    """The samples of ``instances`` (see the module doc) as a map-style dataset: ``{"x": (4, S, S) float32,
    "y": (1, S, S) float32}``; ``photometric`` adds the camera's changes; ``target`` is what ``y`` holds
    (:data:`TARGETS`)."""

    def __init__(self, instances: list[tuple[str, int, int]], size: int, seed: int, photometric: bool,
                 augment_p: float = 1.0, objects=None, pose_priors: float = 0.0, camera_scale: str = "crop",
                 object_light: float = 0.0, target: str = "visible") -> None:
        self.target = check_target(target, object_light)
        self.instances, self.size, self.seed, self.photometric = instances, int(size), int(seed), bool(photometric)
        self.object_light = float(object_light)
        self.augment_p, self.camera_scale = float(augment_p), camera_scale
        self.objects, self.pose_priors = objects, float(pose_priors)
        if self.pose_priors > 0 and objects is None:
            raise ConfigError("outline crops: pose priors need the dataset's objects")
        self.epoch = 0
        self._scenes: dict[str, dict] = {}

    def __len__(self) -> int:
        return len(self.instances)

    def set_epoch(self, epoch: int) -> None:
        self.epoch = int(epoch)

    def arrays(self, i: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Sample ``i`` of the current epoch as uint8 arrays ``(crop, prior, target)``: the target is the visible
        mask, or with ``target="amodal"`` the whole silhouette."""
        scene, im, g = self.instances[i]
        if scene not in self._scenes:
            self._scenes[scene] = bop.read_scene(scene)
        d = self._scenes[scene][im]
        K = d["K"]
        rng = np.random.default_rng(np.random.SeedSequence(self.seed, spawn_key=(self.epoch, i)))
        rgb = bop.read_image(scene, im)
        visible, amodal = bop.read_mask(scene, im, g, visible=True), bop.read_mask(scene, im, g, visible=False)
        gt = d["gt"][g]
        changed = self.photometric and (self.augment_p >= 1.0 or rng.random() < self.augment_p)  # no draw at 1
        if changed and self.camera_scale == "image":  # the camera's changes around the object, then the crop
            (rgb, visible, amodal), K = _around(gt.bbox_obj, K, rgb, visible, amodal)
            rgb = _photometric(rgb, rng, "image")
        drawn = amodal if self.target == "amodal" else visible
        sample = None
        if self.pose_priors > 0 and rng.random() < self.pose_priors:  # no draw without pose priors
            sample = pose_sample(rgb, K, self.objects.get(gt.obj_id), gt.T_cam_obj.R, gt.T_cam_obj.t, drawn,
                                 self.size, rng)
        crop, prior, target = sample or outline_sample(rgb, K, amodal, drawn, self.size, rng)
        if self.photometric and self.object_light > 0 and rng.random() < self.object_light:  # no draw at 0
            crop = ObjectLight(p=1.0)({"rgb": crop, "masks": target[None]}, rng)["rgb"]
        if changed and self.camera_scale == "crop":
            crop = _photometric(crop, rng)
        return crop, prior, target

    def __getitem__(self, i: int) -> dict[str, Any]:
        import torch

        crop, prior, visible = self.arrays(i)
        x = np.concatenate([crop.transpose(2, 0, 1).astype(np.float32) / np.float32(255.0),
                            prior[None].astype(np.float32)], 0)
        return {"x": torch.from_numpy(x), "y": torch.from_numpy(visible[None].astype(np.float32))}


def _collate(samples: list[dict[str, Any]]) -> dict[str, Any]:
    import torch

    return {k: torch.stack([s[k] for s in samples]) for k in ("x", "y")}


def outline_loss(logits, target) -> dict[str, Any]:
    """Binary cross-entropy plus the soft Dice loss per crop (mean over the batch)."""
    from torch.nn import functional as F

    bce = F.binary_cross_entropy_with_logits(logits, target)
    p = logits.sigmoid()
    dice = (1.0 - (2.0 * (p * target).sum((1, 2, 3)) + 1.0) / (p.sum((1, 2, 3)) + target.sum((1, 2, 3)) + 1.0)).mean()
    return {"loss": bce + dice, "bce": bce.detach(), "dice": dice.detach()}


def validate_outlines(net, dataset: OutlineCrops, cfg: OutlineTrainConfig) -> dict[str, Any]:
    """Mean IoU of the predicted masks (visible or amodal, as trained) and of the priors, over the validation
    crops."""
    import torch

    net.eval()
    ious, priors = [], []
    with torch.inference_mode():
        for i in range(0, len(dataset), 32):
            batch = _collate([dataset[j] for j in range(i, min(i + 32, len(dataset)))])
            pred = (net(batch["x"].to(cfg.device)) > 0).cpu().numpy()[:, 0]
            target, prior = batch["y"].numpy()[:, 0] > 0.5, batch["x"].numpy()[:, 3] > 0.5
            for p, t, q in zip(pred, target, prior):
                ious.append(np.count_nonzero(p & t) / max(1, np.count_nonzero(p | t)))
                priors.append(np.count_nonzero(q & t) / max(1, np.count_nonzero(q | t)))
    net.train()
    return {"val_iou": float(np.mean(ious)) if ious else 0.0, "val_prior_iou": float(np.mean(priors)) if priors else 0.0}


def _setup(cfg: OutlineTrainConfig) -> Plan:
    import torch

    from simtest.estimators.templates.mask_model import MaskNet, MaskNetConfig

    roots = data_roots(cfg.data)
    objects = load_dataset_objects(roots[0])
    record = object_record(objects)
    for other in roots[1:] + ([cfg.val] if cfg.val is not None else []):
        check_objects(record, load_dataset_objects(other), where=f"training dataset {roots[0]}")
    train = OutlineCrops(_instances(roots, cfg.split, cfg.min_visib, cfg.max_images), cfg.crop_size, cfg.seed, True,
                         cfg.augment_p, objects, cfg.pose_priors, cfg.camera_scale, cfg.object_light, cfg.target)
    if not len(train):
        raise ConfigError(f"outline training: no instance with visib_fract >= {cfg.min_visib} in {roots}")
    val = None
    if cfg.val is not None:
        val = OutlineCrops(_instances([cfg.val], cfg.val_split, cfg.min_visib, cfg.val_images), cfg.crop_size,
                           cfg.seed + 1, False, objects=objects, pose_priors=cfg.pose_priors,
                           target=cfg.target)
    with torch.random.fork_rng(devices=[]):
        net = MaskNet(MaskNetConfig(crop_size=int(cfg.crop_size), image_skip=bool(cfg.image_skip)))
    net.init_weights(torch.Generator().manual_seed(int(cfg.seed)))
    return Plan(fmt=FORMAT, net=net.to(cfg.device), record=record, objects=objects, dataset=train,
                losses=lambda n, b: outline_loss(n(b["x"].to(cfg.device)), b["y"].to(cfg.device)),
                loss_names=("loss", "bce", "dice"), collate=_collate,
                describe=lambda r: f"loss {r['loss']:.3f} (bce {r['bce']:.3f}, dice {r['dice']:.3f})",
                validate=None if val is None else (lambda n: validate_outlines(n, val, cfg)),
                score="val_iou", score_label="mask IoU")


def train_outlines(cfg: OutlineTrainConfig, *, resume: bool = False, progress: bool = True,
                   log: Callable[[str], None] = print) -> TrainResult:
    """Train the outline network on ``cfg.data``; see the module doc for samples, outputs and resuming.

    Raises:
        ConfigError: Bad settings; an existing run in ``cfg.out`` without ``resume``; datasets of other objects.
        DatasetError: Missing datasets, splits or masks.
    """
    return fit(cfg, lambda: _setup(cfg), resume=resume, progress=progress, log=log)
