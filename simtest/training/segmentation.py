"""The trainer of ``segicp``'s segmentation network (``simtest train segmentation``): its settings, network, loss
and validation, run by the one training loop (:func:`simtest.training.fit.fit`).

Samples come from :class:`simtest.data.PoseDataset` (visible masks after the on-the-fly corruptions of
:func:`simtest.data.augmentation`), optionally as crops; the per-pixel target is the class of the visible
mask covering the pixel (0 = background). Loss: cross-entropy plus the soft Dice loss of the object classes
present in the batch (small objects count as much as the large background).

Every random choice is seeded from ``seed`` (weights, sample order per epoch, corruptions per sample and
epoch). The run folder (``last.pt`` after every epoch, so ``resume=True`` continues after the last finished
epoch; ``best.pt``; ``model.pt``; ``history.json``) is :func:`~simtest.training.fit.fit`'s; with a validation
dataset the mean IoU of the object classes is measured on full images and its best epoch kept in ``best.pt``.
All checkpoints are dicts of tensors and plain types (``torch.load(..., weights_only=True)``)::

    {"format": "simtest-segmentation/1", "net": SegNetConfig dict, "objects": object record,
     "model": state_dict, "epoch": int, "optimizer": state_dict | None, "history": [...], "train": settings,
     "focal_px": median fx of the training images (pixels)}
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from simtest.data import PoseDataset, augmentation, labelled_mixture
from simtest.errors import ConfigError
from simtest.estimators.checkpoint import check_objects, object_record
from simtest.estimators.segicp.infer import FORMAT
from simtest.estimators.segicp.inputs import size_multiple
from simtest.objects.loaders import load_dataset_objects
from simtest.training.fit import Plan, TrainResult, fit, load_warm_start
from simtest.training.settings import check_encoder_settings, check_settings, settings_dict

__all__ = ["SegTrainConfig", "TrainResult", "train_segmentation", "build_segnet", "label_targets", "seg_loss",
           "validate_segmentation", "FORMAT", "data_roots"]


@dataclass(frozen=True)
class SegTrainConfig:
    """Settings of one segmentation training run (recorded in the checkpoints).

    Attributes:
        data, split: Training BOP dataset folder (or several, mixed by :func:`simtest.data.labelled_mixture`)
            and split. out: Run folder.
        data_weights: Mixture weight per dataset of ``data`` (None: proportional to their sizes).
        val, val_split, val_images: Validation dataset (None: none), its split, first N images only.
        epochs, batch_size: Epochs in total (a resumed run continues up to it), images per step.
        lr, weight_decay: Peak AdamW learning rate (warm-up then cosine decay) and weight decay.
        augment, augment_p: Augmentation names (:func:`simtest.data.augmentation`) and the probability
            that a sample is corrupted at all.
        crop: ``(height, width)`` training crops (pixels) around a random object, or None for full images.
        depth_input: Feed relative depth as a fourth channel.
        widths: Encoder channels at strides 2, 4, 8, 16 (``backbone="plain"``).
        backbone: ``"plain"`` (from scratch) or ``"efficientnet-lite0"`` (ImageNet-pretrained encoder, RGB only;
            training crops then need sides that are multiples of 32).
        encoder_lr_scale: The pretrained encoder's learning rate as a fraction of ``lr`` (0: frozen).
        freeze_encoder_bn: The pretrained encoder's batch norms keep their ImageNet statistics.
        device, seed, workers, threads: As ``simtest train keypoints``.
        max_images: Train on the first N images only (None: all).
        init: A segmentation checkpoint (same network settings and object set) whose weights start the run
            instead of a random initialisation (warm start; its SHA-256 is recorded); a resumed run ignores it.
    """

    data: str | tuple[str, ...]
    out: str
    split: str | None = None  # None: the dataset's only split
    val: str | None = None
    val_split: str | None = None
    val_images: int | None = None
    epochs: int = 12
    batch_size: int = 8
    lr: float = 3e-3
    weight_decay: float = 1e-4
    augment: tuple[str, ...] = ("occlusion", "weather")
    augment_p: float = 0.5
    crop: tuple[int, int] | None = None
    depth_input: bool = False
    widths: tuple[int, int, int, int] = (16, 24, 48, 64)
    backbone: str = "plain"
    device: str = "cpu"
    seed: int = 0
    workers: int = 0
    threads: int | None = None
    max_images: int | None = None
    data_weights: tuple[float, ...] | None = None
    encoder_lr_scale: float = 1.0
    freeze_encoder_bn: bool = False
    init: str | None = None

    def __post_init__(self) -> None:
        check_settings(self, "segmentation training")
        check_encoder_settings(self, "segmentation training")
        from simtest.estimators.segicp.model import BACKBONES

        if self.backbone not in BACKBONES:
            raise ConfigError(f"segmentation training: backbone must be one of {', '.join(BACKBONES)}, got "
                              f"{self.backbone!r}")
        if self.backbone != "plain" and (self.depth_input or (self.crop is not None and (self.crop[0] % 32 or
                                                                                          self.crop[1] % 32))):
            raise ConfigError(f"segmentation training: backbone {self.backbone!r} reads RGB only (no --depth-input) "
                              f"and needs crop sides that are multiples of 32, got crop={self.crop}")

    def to_dict(self) -> dict[str, Any]:
        return settings_dict(self)


def build_segnet(num_classes: int, seed: int, depth_input: bool = False, widths=(16, 24, 48, 64),
                 backbone: str = "plain"):
    """A freshly initialised :class:`SegNet`, deterministic in ``seed`` (the global RNG is left as it was); with
    ``backbone="efficientnet-lite0"`` its encoder holds the ImageNet weights (``widths`` are then its own)."""
    import torch

    from simtest.estimators.segicp.model import EFFICIENTNET_WIDTHS, SegNet, SegNetConfig

    cfg = SegNetConfig(num_classes=int(num_classes), depth_input=bool(depth_input), backbone=backbone,
                       widths=tuple(widths) if backbone == "plain" else EFFICIENTNET_WIDTHS)
    with torch.random.fork_rng(devices=[]):
        net = SegNet(cfg)
    net.init_weights(torch.Generator().manual_seed(int(seed)))
    return net


def label_targets(batch: dict[str, Any], size: tuple[int, int]):
    """(B, h, w) int64 class per pixel from a collated batch's visible masks (0 = background), on the padded
    grid ``size``."""
    import torch

    B = batch["rgb"].shape[0]
    H, W = batch["rgb"].shape[-2:]
    target = torch.zeros((B, size[0], size[1]), dtype=torch.int64)
    for k in range(len(batch["labels"])):
        view = target[int(batch["batch_index"][k]), :H, :W]
        view[batch["masks"][k]] = int(batch["labels"][k])
    return target


def seg_loss(logits, target) -> dict[str, Any]:
    """Cross-entropy plus the soft Dice loss of the object classes present in ``target``."""
    import torch
    from torch.nn import functional as F

    ce = F.cross_entropy(logits, target)
    prob = logits.softmax(1)
    onehot = F.one_hot(target, logits.shape[1]).permute(0, 3, 1, 2).to(prob.dtype)
    inter = (prob * onehot).sum((0, 2, 3))[1:]
    union = (prob + onehot).sum((0, 2, 3))[1:]
    present = onehot.sum((0, 2, 3))[1:] > 0
    dice = 1.0 - (2.0 * inter + 1.0) / (union + 1.0)
    dl = dice[present].mean() if bool(present.any()) else torch.zeros((), dtype=prob.dtype)
    return {"loss": ce + dl, "ce": ce.detach(), "dice": dl.detach()}


def _losses(net, batch: dict[str, Any], cfg: SegTrainConfig) -> dict[str, Any]:
    """Cross-entropy + Dice of one batch, its images padded to the network's size multiple, on the device."""
    from simtest.estimators.segicp.model import net_input

    x = net_input(batch["rgb"], batch["depth"], cfg.depth_input, size_multiple(net.cfg.to_dict())).to(cfg.device)
    target = label_targets(batch, tuple(x.shape[-2:])).to(cfg.device)
    return seg_loss(net(x), target)


def validate_segmentation(net, dataset, cfg: SegTrainConfig) -> dict[str, Any]:
    """Mean IoU (object classes present in the validation images) and pixel accuracy on full images."""
    import torch

    from simtest.estimators.segicp.model import net_input

    net.eval()
    C = net.cfg.num_classes + 1
    inter, union = np.zeros(C), np.zeros(C)
    correct = total = 0
    with torch.inference_mode():
        for i in range(len(dataset)):
            s = dataset[i]
            batch = {"rgb": s["rgb"][None], "masks": s["masks"], "labels": s["labels"],
                     "batch_index": torch.zeros(len(s["labels"]), dtype=torch.int64)}
            x = net_input(s["rgb"][None], s["depth"][None], cfg.depth_input, size_multiple(net.cfg.to_dict())).to(cfg.device)
            H, W = s["rgb"].shape[-2:]
            pred = net(x).argmax(1)[0, :H, :W].cpu().numpy()
            tgt = label_targets(batch, tuple(x.shape[-2:]))[0, :H, :W].numpy()
            for c in range(C):
                p, t = pred == c, tgt == c
                inter[c] += np.count_nonzero(p & t)
                union[c] += np.count_nonzero(p | t)
            correct += int(np.count_nonzero(pred == tgt))
            total += pred.size
    net.train()
    seen = union[1:] > 0
    iou = inter[1:][seen] / union[1:][seen]
    return {"val_miou": float(iou.mean()) if len(iou) else 0.0, "val_pixel_acc": correct / max(total, 1)}


def data_roots(data: str | tuple[str, ...] | list[str]) -> list[str]:
    """The training dataset folders of a config's ``data`` (one folder or several)."""
    return [str(data)] if isinstance(data, (str, Path)) else [str(d) for d in data]


def _datasets(cfg: SegTrainConfig, objects: Any):
    """The training dataset (augmented, optionally cropped) and the validation dataset (or None)."""
    train = labelled_mixture(data_roots(cfg.data), cfg.split, cfg.data_weights, int(cfg.seed), objects=objects,
                             transform=augmentation(list(cfg.augment), p=cfg.augment_p), crop=cfg.crop,
                             crop_jitter=0.5, max_images=cfg.max_images)
    val = None
    if cfg.val is not None:
        val = PoseDataset(cfg.val, cfg.val_split, objects=objects, max_images=cfg.val_images)
    return train, val


def _setup(cfg: SegTrainConfig) -> Plan:
    """The run's plan: objects checked across the training and validation datasets, the feeds, the training
    images' focal length, a seeded network on the device, its loss and validation."""
    roots = data_roots(cfg.data)
    objects = load_dataset_objects(roots[0])
    record = object_record(objects)
    for other in roots[1:] + ([cfg.val] if cfg.val is not None else []):
        check_objects(record, load_dataset_objects(other), where=f"training dataset {roots[0]}")
    dataset, val = _datasets(cfg, objects)
    first = dataset.datasets[0] if hasattr(dataset, "datasets") else dataset
    focal = float(first.load_numpy(0)["K"][0, 0])
    net = build_segnet(len(record["obj_ids"]), int(cfg.seed), cfg.depth_input, cfg.widths, cfg.backbone)
    return Plan(fmt=FORMAT, net=net.to(cfg.device), record=record, objects=objects, dataset=dataset,
                losses=lambda n, batch: _losses(n, batch, cfg), loss_names=("loss", "ce", "dice"),
                describe=lambda r: f"loss {r['loss']:.3f} (ce {r['ce']:.3f}, dice {r['dice']:.3f})",
                validate=None if val is None else (lambda n: validate_segmentation(n, val, cfg)),
                score="val_miou", score_label="mIoU", extra={"focal_px": focal},
                warm_start=None if cfg.init is None else (lambda n: load_warm_start(
                    n, cfg.init, objects, FORMAT, "segmentation training", defaults={"backbone": "plain"})))


def train_segmentation(cfg: SegTrainConfig, *, resume: bool = False, progress: bool = True,
                       log: Callable[[str], None] = print) -> TrainResult:
    """Train the segmentation network on ``cfg.data``; see the module doc for outputs and resuming.

    Raises:
        ConfigError: Bad settings; an existing run in ``cfg.out`` without ``resume``; a resumed checkpoint or
            a validation dataset for a different object set.
        DatasetError: Missing dataset or split.
    """
    return fit(cfg, lambda: _setup(cfg), resume=resume, progress=progress, log=log)
