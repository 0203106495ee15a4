"""Training loop of the segmentation network of ``segicp`` (``simtest train segmentation``).

Samples come from :class:`simtest.data.PoseDataset` (visible masks after the on-the-fly corruptions of
:func:`simtest.data.augmentation`), optionally as crops; the per-pixel target is the class of the visible
mask covering the pixel (0 = background). Loss: cross-entropy plus the soft Dice loss of the object classes
present in the batch (small objects count as much as the large background).

Every random choice is seeded from ``seed`` (weights, sample order per epoch, corruptions per sample and
epoch). After each epoch the full state goes to ``OUT/last.pt`` (atomic write), so ``resume=True`` continues
after the last finished epoch; with a validation dataset the mean IoU of the object classes is measured on
full images and the best epoch is kept in ``OUT/best.pt``. The final weights go to ``OUT/model.pt``. All
checkpoints are dicts of tensors and plain types (``torch.load(..., weights_only=True)``)::

    {"format": "simtest-segmentation/1", "net": SegNetConfig dict, "objects": object record,
     "model": state_dict, "epoch": int, "optimizer": state_dict | None, "history": [...], "train": settings,
     "focal_px": median fx of the training images (pixels)}
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from simtest.errors import ConfigError
from simtest.estimators.segicp.infer import FORMAT
from simtest.estimators.training import (TrainResult, check_encoder_settings, check_settings, epoch_loader,
                                        export_beside, lr_at, make_optimizer, optimizer_step, set_lr,
                                        settings_dict, train_mode)

__all__ = ["SegTrainConfig", "train_segmentation", "build_segnet", "label_targets", "seg_loss",
           "FORMAT", "data_roots"]



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
        init: A segmentation checkpoint (e.g. the shipped one) whose weights start the run instead of a random
            initialisation (same network and objects; fresh optimiser and schedule); a resumed run ignores it.
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


def _train_epoch(net, opt, dataset, cfg: SegTrainConfig, epoch: int, steps: int, total: int,
                 progress: bool) -> dict[str, float]:
    """One epoch of optimisation; returns the mean losses."""
    from tqdm import tqdm

    from simtest.estimators.segicp.inputs import size_multiple
    from simtest.estimators.segicp.model import net_input

    loader = epoch_loader(dataset, cfg.batch_size, cfg.workers, cfg.seed, epoch)
    sums = {"loss": 0.0, "ce": 0.0, "dice": 0.0}
    n = 0
    bar = tqdm(loader, desc=f"epoch {epoch + 1}/{cfg.epochs}", unit="batch", disable=not progress,
               dynamic_ncols=True, leave=False)
    for i, batch in enumerate(bar):
        set_lr(opt, lr_at(epoch * steps + i, total, cfg.lr))
        x = net_input(batch["rgb"], batch["depth"], cfg.depth_input, size_multiple(net.cfg.to_dict())).to(cfg.device)
        target = label_targets(batch, tuple(x.shape[-2:])).to(cfg.device)
        losses = seg_loss(net(x), target)
        optimizer_step(net, opt, losses, sums)
        n += 1
        bar.set_postfix(loss=f"{sums['loss'] / n:.3f}")
    bar.close()
    return {k: v / max(n, 1) for k, v in sums.items()}


def validate_segmentation(net, dataset, cfg: SegTrainConfig) -> dict[str, Any]:
    """Mean IoU (object classes present in the validation images) and pixel accuracy on full images."""
    import torch

    from simtest.estimators.segicp.inputs import size_multiple
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
    from simtest.data import PoseDataset, augmentation, labelled_mixture

    train = labelled_mixture(data_roots(cfg.data), cfg.split, cfg.data_weights, int(cfg.seed), objects=objects,
                             transform=augmentation(list(cfg.augment), p=cfg.augment_p), crop=cfg.crop,
                             crop_jitter=0.5, max_images=cfg.max_images)
    val = None
    if cfg.val is not None:
        val = PoseDataset(cfg.val, cfg.val_split, objects=objects, max_images=cfg.val_images)
    return train, val


def train_segmentation(cfg: SegTrainConfig, *, resume: bool = False, progress: bool = True,
                       log: Callable[[str], None] = print) -> TrainResult:
    """Train the segmentation network on ``cfg.data``; see the module doc for outputs and resuming.

    Raises:
        ConfigError: Bad settings; an existing run in ``cfg.out`` without ``resume``; a resumed checkpoint or
            a validation dataset for a different object set.
        DatasetError: Missing dataset or split.
    """
    import torch

    from simtest.estimators.keypoints.checkpoint import check_objects, load_checkpoint, object_record, save_checkpoint
    from simtest.io.files import atomic_write_text
    from simtest.objects.loaders import load_dataset_objects

    t_start = time.perf_counter()
    if cfg.threads is not None:
        torch.set_num_threads(int(cfg.threads))
    if str(cfg.device).startswith("cuda") and not torch.cuda.is_available():
        raise ConfigError(f"device {cfg.device!r} asked but CUDA is not available to this torch build; use cpu")
    out = Path(cfg.out)
    last_path, best_path, model_path = out / "last.pt", out / "best.pt", out / "model.pt"
    if last_path.exists() and not resume:
        raise ConfigError(f"{out} already holds a run (last.pt); pass resume to continue it or choose another "
                          "output folder")
    roots = data_roots(cfg.data)
    objects = load_dataset_objects(roots[0])
    record = object_record(objects)
    for other in roots[1:] + ([cfg.val] if cfg.val is not None else []):
        check_objects(record, load_dataset_objects(other), where=f"training dataset {roots[0]}")
    dataset, val = _datasets(cfg, objects)
    first = dataset.datasets[0] if hasattr(dataset, "datasets") else dataset
    focal = float(first.load_numpy(0)["K"][0, 0])
    net = build_segnet(len(record["obj_ids"]), int(cfg.seed), cfg.depth_input, cfg.widths, cfg.backbone).to(cfg.device)
    opt = make_optimizer(net, cfg.lr, cfg.weight_decay, cfg.encoder_lr_scale)
    history: list[dict[str, Any]] = []
    start_epoch, best = 0, -1.0
    if resume and last_path.exists():
        ck = load_checkpoint(last_path, fmt=FORMAT)
        check_objects(ck["objects"], objects, where=f"checkpoint {last_path}")
        net.load_state_dict(ck["model"])
        opt.load_state_dict(ck["optimizer"])
        history = list(ck["history"])
        start_epoch = int(ck["epoch"]) + 1
        best = max([h.get("val_miou", -1.0) for h in history] + [-1.0])
        log(f"resuming {out} after epoch {start_epoch} of {cfg.epochs}")
    elif cfg.init is not None:
        ck = load_checkpoint(cfg.init, fmt=FORMAT)
        check_objects(ck["objects"], objects, where=f"init checkpoint {cfg.init}")
        if {"backbone": "plain", **ck["net"]} != net.cfg.to_dict():  # checkpoints before backbones were plain
            raise ConfigError(f"segmentation training: init checkpoint {cfg.init} has the network {ck['net']}, this "
                              f"run builds {net.cfg.to_dict()}; match depth_input, widths and backbone")
        net.load_state_dict(ck["model"])
    steps = len(dataset) // cfg.batch_size or 1

    def checkpoint(epoch: int, with_optimizer: bool) -> dict[str, Any]:
        return {"format": FORMAT, "net": net.cfg.to_dict(), "objects": record,
                "model": {k: v.detach().cpu() for k, v in net.state_dict().items()}, "epoch": int(epoch),
                "optimizer": opt.state_dict() if with_optimizer else None, "history": history,
                "train": cfg.to_dict(), "focal_px": focal}

    for epoch in range(start_epoch, cfg.epochs):
        train_mode(net, cfg.freeze_encoder_bn)
        t0 = time.perf_counter()
        rec: dict[str, Any] = {"epoch": epoch, **_train_epoch(net, opt, dataset, cfg, epoch, steps,
                                                              steps * cfg.epochs, progress)}
        rec["train_seconds"] = time.perf_counter() - t0
        msg = f"epoch {epoch + 1}/{cfg.epochs}: loss {rec['loss']:.3f} (ce {rec['ce']:.3f}, dice {rec['dice']:.3f}), " \
              f"{rec['train_seconds']:.0f} s"
        if val is not None:
            rec.update(validate_segmentation(net, val, cfg))
            msg += f"; val mIoU {100 * rec['val_miou']:.1f} %"
        history.append(rec)
        if val is not None and rec["val_miou"] > best:
            best = rec["val_miou"]
            save_checkpoint(best_path, checkpoint(epoch, False))
        log(msg)
        save_checkpoint(last_path, checkpoint(epoch, True))
        atomic_write_text(out / "history.json", json.dumps(history, indent=2) + "\n")
    final_epoch = history[-1]["epoch"] if history else cfg.epochs - 1
    save_checkpoint(model_path, checkpoint(final_epoch, False))
    export_beside(model_path, best_path)
    return TrainResult(model_path=model_path, last_path=last_path,
                          best_path=best_path if best_path.exists() else None, history=history,
                          seconds=time.perf_counter() - t_start)
