"""Training loop of the keypoint estimator (``simtest train keypoints``).

Every random choice is seeded from ``seed``: weights from a ``torch.Generator``, the sample order of epoch
``e`` from a generator keyed by ``(seed, e)``, corruptions per sample by ``(seed, e, index)``
(:func:`simtest.data.sample_rng`). After each epoch the full state goes to ``OUT/last.pt`` (atomic write), so
``resume=True`` continues after the last finished epoch; with a validation dataset, ADD(-S)-0.1d is measured
with :func:`simtest.evaluation.run.evaluate` (ground-truth masks as targets, no VSD) and the best epoch is kept in
``OUT/best.pt``. The final weights go to ``OUT/model.pt``. All three load with ``torch.load(...,
weights_only=True)`` and record the network config, the training settings and the object set (ids, names,
mesh hashes, keypoints).
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from simtest.errors import ConfigError
from simtest.estimators.training import (TrainResult, check_settings, epoch_loader, export_beside, lr_at,
                                        optimizer_step, pad16, settings_dict)

__all__ = ["TrainConfig", "TrainResult", "train_keypoints", "build_model"]


@dataclass(frozen=True)
class TrainConfig:
    """Settings of one training run (all recorded in the checkpoints).

    Attributes:
        data: Training BOP dataset folder. split: its split folder.
        out: Run folder (checkpoints, ``history.json``).
        val: Validation dataset folder (None: no validation). val_split: its split folder.
        val_images: Validate on the first N images only (None: all).
        epochs: Epochs in total (a resumed run continues up to this number).
        batch_size: Images per step.
        lr: Peak learning rate (AdamW; linear warm-up over the first 3 % of steps, then cosine decay to 2 %).
        weight_decay: AdamW weight decay.
        augment: Augmentation names (``occlusion``, ``weather``, ``depth``; see :func:`simtest.data.augmentation`).
        augment_p: Probability that a training sample is corrupted at all.
        device: ``cpu`` or ``cuda``.
        seed: Seed of everything random.
        workers: DataLoader worker processes.
        keypoints: ``bbox`` (8 corners) or ``fps``.
        crop: ``(height, width)`` training crops around objects, or None for full images.
        seg_weight: Weight of the segmentation loss against the keypoint loss.
        widths, decoder: Network channels (see :class:`~simtest.estimators.keypoints.model.NetConfig`).
        threads: torch CPU threads (None: torch's default).
    """

    data: str
    out: str
    split: str = "train_pbr"
    val: str | None = None
    val_split: str = "train_pbr"
    val_images: int | None = None
    epochs: int = 20
    batch_size: int = 8
    lr: float = 2e-3
    weight_decay: float = 1e-4
    augment: tuple[str, ...] = ("occlusion", "weather")
    augment_p: float = 0.8
    device: str = "cpu"
    seed: int = 0
    workers: int = 1
    keypoints: str = "bbox"
    crop: tuple[int, int] | None = None
    seg_weight: float = 2.0
    widths: tuple[int, int, int, int] = (16, 32, 64, 96)
    decoder: tuple[int, int] = (64, 48)
    threads: int | None = None

    def __post_init__(self) -> None:
        check_settings(self, "keypoint training")

    def to_dict(self) -> dict[str, Any]:
        return settings_dict(self)


def build_model(num_classes: int, num_keypoints: int, seed: int, widths=(16, 32, 64, 96), decoder=(64, 48)):
    """A freshly initialised :class:`KeypointNet`, deterministic in ``seed`` (the global RNG is left as it was)."""
    import torch

    from simtest.estimators.keypoints.model import KeypointNet, NetConfig

    cfg = NetConfig(num_classes=int(num_classes), num_keypoints=int(num_keypoints), widths=tuple(widths),
                    decoder=tuple(decoder))
    with torch.random.fork_rng(devices=[]):
        net = KeypointNet(cfg)
    net.init_weights(torch.Generator().manual_seed(int(seed)))
    return net


def validate(net, record: dict[str, Any], val: str, split: str, device: str, max_images: int | None
             ) -> dict[str, Any]:
    """ADD(-S)-0.1d (overall and per object) of the network on a validation dataset (GT masks as targets)."""
    from simtest.estimators.keypoints.infer import KeypointEstimator
    from simtest.evaluation.run import evaluate

    est = KeypointEstimator(model=net, objects_record=record, device=device)
    rep = evaluate(val, est, split=split, vsd=False, progress=False, max_images=max_images)
    net.train()
    return {"val_add_s_or_add_01d": float(rep.overall["add_s_or_add_01d"]),
            "val_per_object": {str(o): float(m["add_s_or_add_01d"]) for o, m in rep.per_object.items()},
            "val_median_re_deg": float(rep.overall["median_re_deg"]),
            "val_median_te_m": float(rep.overall["median_te_m"])}


def _train_epoch(net, opt, dataset, cfg: TrainConfig, epoch: int, steps_per_epoch: int, total_steps: int,
                 progress: bool) -> tuple[dict[str, float], int]:
    """One epoch of optimisation (cosine learning rate per step); returns the summed losses and the batch count."""
    import torch
    from tqdm import tqdm

    from simtest.estimators.keypoints.loss import make_targets, total_loss

    loader = epoch_loader(dataset, cfg.batch_size, cfg.workers, cfg.seed, epoch)
    sums = {"loss": 0.0, "seg": 0.0, "kp": 0.0}
    n = 0
    bar = tqdm(loader, desc=f"epoch {epoch + 1}/{cfg.epochs}", unit="batch", disable=not progress,
               dynamic_ncols=True, leave=False)
    for i, batch in enumerate(bar):
        step = epoch * steps_per_epoch + i
        for g in opt.param_groups:
            g["lr"] = lr_at(step, total_steps, cfg.lr)
        x = pad16(batch["rgb"].to(cfg.device))
        pred = net(x)
        batch = {k: (v.to(cfg.device) if torch.is_tensor(v) else v) for k, v in batch.items()}
        batch["rgb"] = x
        tg = make_targets(batch, tuple(pred["seg"].shape[-2:]), net.cfg.stride, net.cfg.offset_scale)
        losses = total_loss(pred, tg, cfg.seg_weight)
        optimizer_step(net, opt, losses, sums)
        n += 1
        bar.set_postfix(loss=f"{sums['loss'] / n:.3f}", seg=f"{sums['seg'] / n:.3f}", kp=f"{sums['kp'] / n:.3f}")
    bar.close()
    return sums, n


def train_keypoints(cfg: TrainConfig, *, resume: bool = False, progress: bool = True,
                    log: Callable[[str], None] = print) -> TrainResult:
    """Train the keypoint network on ``cfg.data``; see the module doc for outputs and resuming.

    Raises:
        ConfigError: Bad settings; an existing run in ``cfg.out`` without ``resume``; a resumed checkpoint or
            a validation dataset for a different object set.
        DatasetError: Missing dataset or split.
    """
    import torch

    from simtest.data import PoseDataset, augmentation
    from simtest.estimators.keypoints.checkpoint import (FORMAT, check_objects, load_checkpoint, object_record,
                                                         save_checkpoint)
    from simtest.objects.loaders import load_dataset_objects
    from simtest.io.files import atomic_write_text

    t_start = time.perf_counter()
    if cfg.threads is not None:
        torch.set_num_threads(int(cfg.threads))
    if str(cfg.device).startswith("cuda") and not torch.cuda.is_available():
        raise ConfigError(f"device {cfg.device!r} asked but CUDA is not available to this torch build "
                          f"({torch.__version__}); use --device cpu")
    out = Path(cfg.out)
    last_path, best_path, model_path = out / "last.pt", out / "best.pt", out / "model.pt"
    if last_path.exists() and not resume:
        raise ConfigError(f"{out} already holds a run (last.pt); pass resume to continue it or choose another "
                          "output folder")
    objects = load_dataset_objects(cfg.data)
    record = object_record(objects, cfg.keypoints)
    if cfg.val is not None:
        check_objects(record, load_dataset_objects(cfg.val), where=f"training dataset {cfg.data}")
        # i.e. the validation dataset {cfg.val} must hold the same objects
    dataset = PoseDataset(cfg.data, cfg.split, objects=objects, keypoints=cfg.keypoints,
                          transform=augmentation(list(cfg.augment), p=cfg.augment_p), seed=int(cfg.seed),
                          crop=cfg.crop)
    J = len(record["keypoints"][0])
    net = build_model(dataset.num_classes, J, int(cfg.seed), cfg.widths, cfg.decoder).to(cfg.device)
    opt = torch.optim.AdamW(net.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    history: list[dict[str, Any]] = []
    start_epoch = 0
    best = -1.0
    if resume and last_path.exists():
        ck = load_checkpoint(last_path)
        check_objects(ck["objects"], objects, where=f"checkpoint {last_path}")
        net.load_state_dict(ck["model"])
        opt.load_state_dict(ck["optimizer"])
        history = list(ck["history"])
        start_epoch = int(ck["epoch"]) + 1
        best = max([h.get("val_add_s_or_add_01d", -1.0) for h in history] + [-1.0])
        log(f"resuming {out} after epoch {start_epoch} of {cfg.epochs}")
    steps_per_epoch = len(dataset) // cfg.batch_size or 1
    total_steps = steps_per_epoch * cfg.epochs

    def checkpoint(epoch: int, with_optimizer: bool) -> dict[str, Any]:
        return {"format": FORMAT, "net": net.cfg.to_dict(), "objects": record,
                "model": {k: v.detach().cpu() for k, v in net.state_dict().items()}, "epoch": int(epoch),
                "optimizer": opt.state_dict() if with_optimizer else None, "history": history,
                "train": cfg.to_dict()}

    net.train()
    for epoch in range(start_epoch, cfg.epochs):
        t0 = time.perf_counter()
        sums, n = _train_epoch(net, opt, dataset, cfg, epoch, steps_per_epoch, total_steps, progress)
        rec: dict[str, Any] = {"epoch": epoch, **{k: v / max(n, 1) for k, v in sums.items()},
                               "train_seconds": time.perf_counter() - t0}
        if cfg.val is not None:
            t1 = time.perf_counter()
            rec.update(validate(net, record, cfg.val, cfg.val_split, cfg.device, cfg.val_images))
            rec["val_seconds"] = time.perf_counter() - t1
        history.append(rec)
        msg = (f"epoch {epoch + 1}/{cfg.epochs}: loss {rec['loss']:.3f} (seg {rec['seg']:.3f}, kp {rec['kp']:.3f}), "
               f"{rec['train_seconds']:.0f} s")
        if "val_add_s_or_add_01d" in rec:
            msg += f"; val ADD(-S)-0.1d {100 * rec['val_add_s_or_add_01d']:.1f} %"
            if rec["val_add_s_or_add_01d"] > best:
                best = rec["val_add_s_or_add_01d"]
                save_checkpoint(best_path, checkpoint(epoch, False))
        log(msg)
        save_checkpoint(last_path, checkpoint(epoch, True))
        atomic_write_text(out / "history.json", json.dumps(history, indent=2) + "\n")
    final_epoch = history[-1]["epoch"] if history else cfg.epochs - 1
    save_checkpoint(model_path, checkpoint(final_epoch, False))
    export_beside(model_path, best_path)
    return TrainResult(model_path=model_path, last_path=last_path, best_path=best_path if best_path.exists() else None,
                       history=history, seconds=time.perf_counter() - t_start)
