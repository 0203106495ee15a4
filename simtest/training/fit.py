"""The one training loop of the learned networks (torch imported lazily): :func:`fit` runs the epochs of a
network that a trainer (:mod:`.keypoints`, :mod:`.segmentation`) has set up as a :class:`Plan`.

A run folder ``OUT`` holds ``last.pt`` (the full state after every epoch, written atomically: ``resume=True``
continues after the last finished epoch), ``best.pt`` (the epoch with the best validation score, when the plan
validates), ``model.pt`` (the final weights), ``history.json`` (one record per epoch: mean losses, seconds,
validation scores) and the ONNX files of ``model.pt`` and ``best.pt``. Every checkpoint is a dict of tensors and
plain types (:mod:`simtest.estimators.checkpoint`)::

    {"format": plan.fmt, "net": network config dict, "objects": object record, "model": state_dict,
     "epoch": int (0-based), "optimizer": state_dict | None, "history": [...], "train": settings
     (+ "init_sha256" of a warm start), **plan.extra}

Every random choice derives from the run's seed: the weights (the trainer's seeded network), the sample order of
epoch ``e`` (:func:`~simtest.training.batches.epoch_generator`), the per-sample corruptions (the feed), so a
resumed run ends with the same weights as an uninterrupted one.
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from simtest.errors import ConfigError
from simtest.estimators.checkpoint import check_objects, load_checkpoint, save_checkpoint
from simtest.estimators.onnx_export import export_checkpoint
from simtest.estimators.onnx_net import file_sha256
from simtest.io.files import atomic_write_text
from simtest.training.batches import epoch_loader
from simtest.training.optim import lr_at, make_optimizer, optimizer_step, set_lr, train_mode

__all__ = ["Plan", "TrainResult", "fit", "export_beside", "eta_text", "load_warm_start"]

logger = logging.getLogger(__name__)


@dataclass
class TrainResult:
    """What a run produced: checkpoint paths, per-epoch history (losses, validation scores), wall time of this
    call (s)."""

    model_path: Path
    last_path: Path
    best_path: Path | None
    history: list[dict[str, Any]] = field(default_factory=list)
    seconds: float = 0.0


@dataclass
class Plan:
    """What a network's trainer hands :func:`fit`.

    Attributes:
        fmt: The checkpoints' ``format`` entry.
        net: The seeded torch network (on the run's device), with ``cfg.to_dict()``.
        record: The object record of the objects it learns (:func:`simtest.estimators.checkpoint.object_record`).
        objects: Those objects (a resumed run's checkpoint is checked against them).
        dataset: The training feed (``len``, ``set_epoch``).
        losses: ``(net, batch) -> {"loss": tensor, name: tensor, ...}`` of one batch (moved to the device).
        loss_names: The losses summed over an epoch (mean per batch in the history).
        describe: The losses of a history record as a log phrase (``"loss 1.2 (ce 0.6, dice 0.6)"``).
        collate: Joins samples into a batch (None: :func:`simtest.data.collate`).
        skip: ``batch -> True`` for a batch to leave out (it still counts as a step of the schedule).
        validate: ``net -> {score: value, ...}`` after every epoch (None: no validation).
        score: The history key whose best epoch goes to ``best.pt``; score_label: its name in the log.
        warm_start: ``net -> SHA-256`` loading a start checkpoint into a new run (not a resumed one).
        extra: More entries of every checkpoint.
    """

    fmt: str
    net: Any
    record: dict[str, Any]
    objects: Any
    dataset: Any
    losses: Callable[[Any, dict[str, Any]], dict[str, Any]]
    loss_names: tuple[str, ...]
    describe: Callable[[dict[str, Any]], str]
    collate: Callable[[list], Any] | None = None
    skip: Callable[[dict[str, Any]], bool] | None = None
    validate: Callable[[Any], dict[str, Any]] | None = None
    score: str | None = None
    score_label: str = ""
    warm_start: Callable[[Any], str] | None = None
    extra: dict[str, Any] = field(default_factory=dict)


def export_beside(*checkpoints: Path | None) -> list[Path]:
    """The ONNX file of each existing checkpoint, written beside it (``model.pt`` -> ``model.onnx``), so the run
    is evaluated without torch (:mod:`simtest.estimators.onnx_net`). Without the exporter's packages (onnx,
    onnxscript) the checkpoints stay usable with torch and a warning names the command that converts them."""
    out = []
    for ckpt in checkpoints:
        if ckpt is None or not Path(ckpt).is_file():
            continue
        try:
            out.append(export_checkpoint(ckpt))
        except ConfigError as exc:
            logger.warning("no ONNX file for %s (%s); convert it later with: simtest export %s", ckpt, exc, ckpt)
    return out


def eta_text(seconds: float) -> str:
    """A remaining time for the log: ``"40 s"``, ``"12 min"``, ``"2.5 h"``."""
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 90 * 60:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def _prepare(cfg: Any, resume: bool) -> Path:
    """Torch threads, the device, and the run folder (``OUT``) of a run that may start there."""
    import torch

    if cfg.threads is not None:
        torch.set_num_threads(int(cfg.threads))
    if str(cfg.device).startswith("cuda") and not torch.cuda.is_available():
        raise ConfigError(f"device {cfg.device!r} asked but CUDA is not available to this torch build "
                          f"({torch.__version__}); use --device cpu")
    out = Path(cfg.out)
    if (out / "last.pt").exists() and not resume:
        raise ConfigError(f"{out} already holds a run (last.pt); pass resume to continue it or choose another "
                          "output folder")
    return out


def _epoch(plan: Plan, opt: Any, cfg: Any, epoch: int, steps: int, total: int, progress: bool
           ) -> dict[str, float]:
    """One epoch of optimisation (the learning rate set per step); the mean losses per batch."""
    from tqdm import tqdm

    sums = {k: 0.0 for k in plan.loss_names}
    n = 0
    bar = tqdm(epoch_loader(plan.dataset, cfg.batch_size, cfg.workers, cfg.seed, epoch, plan.collate),
               desc=f"epoch {epoch + 1}/{cfg.epochs}", unit="batch", disable=not progress, dynamic_ncols=True,
               leave=False)
    for i, batch in enumerate(bar):
        if plan.skip is not None and plan.skip(batch):
            continue
        set_lr(opt, lr_at(epoch * steps + i, total, cfg.lr))
        optimizer_step(plan.net, opt, plan.losses(plan.net, batch), sums)
        n += 1
        bar.set_postfix({k: f"{v / n:.3f}" for k, v in sums.items()})
    bar.close()
    return {k: v / max(n, 1) for k, v in sums.items()}


def fit(cfg: Any, setup: Callable[[], Plan], *, resume: bool = False, progress: bool = True,
        log: Callable[[str], None] = print) -> TrainResult:
    """Train the network ``setup()`` plans for ``cfg.epochs`` epochs (see the module doc for the files).

    ``cfg`` carries the shared settings: ``out``, ``epochs``, ``batch_size``, ``lr``, ``weight_decay``,
    ``encoder_lr_scale``, ``freeze_encoder_bn``, ``seed``, ``device``, ``workers``, ``threads`` and
    ``to_dict()``. ``setup`` runs after the run folder and the device are checked.

    Raises:
        ConfigError: An existing run in ``cfg.out`` without ``resume``; CUDA asked but missing; a resumed
            checkpoint of another format or object set.
    """
    t_start = time.perf_counter()
    out = _prepare(cfg, resume)
    last_path, best_path, model_path = out / "last.pt", out / "best.pt", out / "model.pt"
    plan = setup()
    net = plan.net
    resuming = resume and last_path.exists()
    # a resumed run takes its weights from last.pt; a warm start only begins a new one
    init_sha = plan.warm_start(net) if plan.warm_start is not None and not resuming else None
    opt = make_optimizer(net, cfg.lr, cfg.weight_decay, cfg.encoder_lr_scale)
    history: list[dict[str, Any]] = []
    start_epoch, best = 0, -1.0
    if resuming:
        ck = load_checkpoint(last_path, fmt=plan.fmt)
        check_objects(ck["objects"], plan.objects, where=f"checkpoint {last_path}")
        init_sha = ck["train"].get("init_sha256")
        net.load_state_dict(ck["model"])
        opt.load_state_dict(ck["optimizer"])
        history = list(ck["history"])
        start_epoch = int(ck["epoch"]) + 1
        best = max([h.get(plan.score, -1.0) for h in history] + [-1.0]) if plan.score else -1.0
        log(f"resuming {out} after epoch {start_epoch} of {cfg.epochs}")
    steps = len(plan.dataset) // cfg.batch_size or 1

    def checkpoint(epoch: int, with_optimizer: bool) -> dict[str, Any]:
        return {"format": plan.fmt, "net": net.cfg.to_dict(), "objects": plan.record,
                "model": {k: v.detach().cpu() for k, v in net.state_dict().items()}, "epoch": int(epoch),
                "optimizer": opt.state_dict() if with_optimizer else None, "history": history,
                "train": {**cfg.to_dict(), **({"init_sha256": init_sha} if init_sha else {})}, **plan.extra}

    t_epochs = time.perf_counter()
    for epoch in range(start_epoch, cfg.epochs):
        train_mode(net, cfg.freeze_encoder_bn)
        t0 = time.perf_counter()
        rec: dict[str, Any] = {"epoch": epoch, **_epoch(plan, opt, cfg, epoch, steps, steps * cfg.epochs, progress)}
        rec["train_seconds"] = time.perf_counter() - t0
        if plan.validate is not None:
            t1 = time.perf_counter()
            rec.update(plan.validate(net))
            rec["val_seconds"] = time.perf_counter() - t1
        history.append(rec)
        msg = f"epoch {epoch + 1}/{cfg.epochs}: {plan.describe(rec)}, {rec['train_seconds']:.0f} s"
        if plan.score is not None and plan.score in rec:
            msg += f"; val {plan.score_label} {100 * rec[plan.score]:.1f} %"
            if rec[plan.score] > best:
                best = rec[plan.score]
                save_checkpoint(best_path, checkpoint(epoch, False))
        left = cfg.epochs - 1 - epoch
        if left:
            done = epoch + 1 - start_epoch
            msg += f" (about {eta_text((time.perf_counter() - t_epochs) / done * left)} left)"
        log(msg)
        save_checkpoint(last_path, checkpoint(epoch, True))
        atomic_write_text(out / "history.json", json.dumps(history, indent=2) + "\n")
    final_epoch = history[-1]["epoch"] if history else cfg.epochs - 1
    save_checkpoint(model_path, checkpoint(final_epoch, False))
    export_beside(model_path, best_path)
    return TrainResult(model_path=model_path, last_path=last_path, best_path=best_path if best_path.exists() else None,
                       history=history, seconds=time.perf_counter() - t_start)


def load_warm_start(net: Any, init: str | Path, objects: Any, fmt: str, what: str,
                    defaults: dict[str, Any] | None = None) -> str:
    """Load the weights of checkpoint ``init`` into ``net`` to start a new run from them (a warm start);
    returns the file's SHA-256 (recorded in the run's checkpoints).

    Args:
        net: The freshly built network (its ``cfg.to_dict()`` must equal the checkpoint's network).
        init: The checkpoint (``model.pt``, ``best.pt`` or ``last.pt`` of an earlier run).
        objects: The run's object set (the checkpoint's must be the same).
        fmt: The checkpoint format this trainer writes.
        what: The trainer's name for errors (``"keypoint training"``).
        defaults: Network settings a checkpoint older than them did not record (their value then).

    Raises:
        ConfigError: A missing or unreadable file, another format, another object set or another network
            configuration (naming the fields that differ).
    """
    ck = load_checkpoint(init, fmt=fmt)
    check_objects(ck["objects"], objects, where=f"init checkpoint {init}")
    mine, theirs = net.cfg.to_dict(), {**(defaults or {}), **ck["net"]}
    diff = sorted(k for k in set(mine) | set(theirs) if mine.get(k) != theirs.get(k))
    if diff:
        raise ConfigError(f"{what}: init checkpoint {init} has another network: "
                          + "; ".join(f"{k} {theirs.get(k)!r} there, {mine.get(k)!r} here" for k in diff)
                          + " (give the options it was trained with)")
    net.load_state_dict(ck["model"])
    return file_sha256(init)

