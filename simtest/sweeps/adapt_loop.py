"""The loop of ``simtest adapt --loop``: does spending the next images where the estimator fails help?

Two arms with the same budget: ``adapted`` (images from ``adapted.toml``) and ``control`` (the same number from
``uniform.toml``, same seed). For each arm: generate its dataset, continue training the estimator's network from
the same checkpoint (the shipped one unless the train config names another) on the union of the original
training data (``data`` of the train config, may be empty) and the arm's images, with the same epochs, batch
size, learning rate and seed, so both arms take the same number of steps; then evaluate the new network on every
condition dataset of the sweep (the sweep's own data folders: the same images and corruptions as its cells),
written as the sweep's pose cells (``OUT/sweeps/<arm>/cells/...``). ``adapt.json`` / ``adapt.md``: per condition
the ADD(-S)-0.1d score with its 95 % Wilson interval before (the sweep's cells), for the control and adapted,
the images and CPU minutes per arm, and whether adapted beat the control on the sweep's weakest condition by
more than the control's interval without losing more than it on clean images.

The networks trained here: ``segicp``'s segmentation network and ``keypoints``' crop network (its detector is
kept); other estimators are refused with the list. Both arms start from the train config's ``init``, else the
checkpoint the sweep's estimator ran with (its ``checkpoint`` option, else the shipped one it chose).
This is an orchestration module: generation, training and evaluation are imported lazily.
"""

from __future__ import annotations

import json
import os
import re
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from simtest.errors import ConfigError
from simtest.io.files import atomic_write_json, atomic_write_text
from simtest.metrics.intervals import wilson_interval
from simtest.schema import bounds, build, read_config_file
from simtest.sweeps import cells
from simtest.sweeps.adapt import AdaptFit
from simtest.sweeps.adapt_targets import TargetResult, cell_dataset, read_targets

__all__ = ["LoopTrainConfig", "load_train_config", "run_loop", "condition_scores", "TRAINABLE", "ARMS"]

#: Estimators whose network the loop trains, and the model ``simtest train`` calls it.
TRAINABLE = {"segicp": "segmentation", "keypoints": "keypoints"}
#: The two arms, in table order.
ARMS = ("control", "adapted")


@dataclass(frozen=True)
class LoopTrainConfig:
    """How both arms continue training (``--train-config F``, TOML or JSON; every field optional).

    ``data``: the original training datasets the new images join (empty: the new images alone); ``init``: the
    checkpoint both arms start from (None: the one the sweep's estimator ran with, its ``checkpoint`` option,
    else the shipped network); ``epochs``, ``batch_size``, ``lr`` (peak learning rate), ``seed``, ``augment``,
    ``threads`` as ``simtest train segmentation`` / ``simtest train keypoints``; ``max_images`` (segmentation
    only) caps the training images; the network's own settings (depth input, widths, crop, keypoints, heads)
    are the init checkpoint's."""

    data: tuple[str, ...] = ()
    init: str | None = None
    epochs: int = field(default=2, metadata=bounds(1, 10_000))
    batch_size: int = field(default=8, metadata=bounds(1, 4096))
    lr: float = field(default=1e-3, metadata=bounds(1e-8, 10.0))
    seed: int = field(default=0, metadata=bounds(0, 2**63 - 1))
    augment: tuple[str, ...] = ("occlusion", "weather")
    threads: int | None = field(default=None, metadata=bounds(1, 1024))
    max_images: int | None = field(default=None, metadata=bounds(1, 10_000_000))


def load_train_config(path: str | Path | None) -> LoopTrainConfig:
    """The loop's training settings from a TOML or JSON file (None: the defaults); errors name the field."""
    if path is None:
        return LoopTrainConfig()
    return build(LoopTrainConfig, read_config_file(path), prefix="", source=str(path))


def _cpu_s() -> float:
    """CPU seconds of this process and its reaped children (user + system); a worker process still alive is
    not counted, so ``wall_min`` is recorded beside it."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def condition_scores(targets: list[TargetResult]) -> dict[str, dict[str, Any]]:
    """Per condition: ``score`` (the share of targets that did not fail: ADD(-S)-0.1d), its 95 % Wilson interval
    ``ci95`` and the target count ``n``."""
    out: dict[str, dict[str, Any]] = {}
    for cond in sorted({t.condition for t in targets}):
        rows = [t for t in targets if t.condition == cond]
        ok = sum(not t.failed for t in rows)
        out[cond] = {"score": ok / len(rows), "ci95": list(wilson_interval(ok, len(rows))), "n": len(rows)}
    return out


def _sweep_settings(sweep: Path, estimator: str) -> tuple[Any, Any]:
    """The sweep's config and the entry of ``estimator``."""
    from simtest.sweeps.grid import SweepConfig

    cfg = SweepConfig.from_dict(json.loads((sweep / "sweep_config.json").read_text()))
    entry = next(e for e in cfg.estimators if e.name == estimator)
    if entry.estimator not in TRAINABLE:
        raise ConfigError(f"the loop trains the networks of {sorted(TRAINABLE)}; estimator {estimator!r} is "
                          f"{entry.estimator!r} (fit it without --loop, or sweep one of those)")
    return cfg, entry


def _first_cell_dataset(sweep: Path, name: str) -> Path:
    """The dataset of the first finished pose cell of ``name`` in the sweep."""
    for cdir in sorted((sweep / "cells" / name).iterdir()):
        pose = cells.cell_dir(sweep, name, cdir.name, "pose")
        if cells.is_finished(pose):
            return cell_dataset(sweep, cdir.name, json.loads((pose / "cell.json").read_text()))
    raise ConfigError(f"estimator {name!r} has no finished pose cell in {str(sweep)!r}")


def _init_checkpoint(train: LoopTrainConfig, entry: Any, sweep: Path, name: str) -> tuple[str, dict]:
    """The checkpoint both arms start from and its recorded training settings: ``init``, else the sweep
    entry's ``checkpoint`` option, else the shipped network the estimator ran with (keypoints: the one chosen
    for the sweep's objects; segicp: its shipped one)."""
    import torch

    if train.init is not None:
        path = str(train.init)
    elif dict(entry.options).get("checkpoint"):
        path = str(dict(entry.options)["checkpoint"])
    elif entry.estimator == "keypoints":
        from simtest.estimators.keypoints.crop_infer import CROP_FORMAT
        from simtest.estimators.shipped import choose
        from simtest.objects.loaders import load_dataset_objects

        objects = load_dataset_objects(_first_cell_dataset(sweep, name))
        path = str(choose("keypoints", CROP_FORMAT, objects, what="adapt --loop (keypoints)").path)
    else:
        from simtest.estimators.segicp.infer import default_checkpoint
        path = str(default_checkpoint())
    if Path(path).suffix == ".onnx":
        path = str(Path(path).with_suffix(".pt"))
    if not Path(path).is_file():
        raise ConfigError(f"the init checkpoint {path!r} does not exist (training needs the .pt checkpoint)")
    return path, dict(torch.load(path, weights_only=True, map_location="cpu").get("train") or {})


def _train_segmentation(train: LoopTrainConfig, init: str, settings: dict, data: tuple[str, ...], out: Path,
                        progress: bool) -> Path:
    from simtest.training.segmentation import SegTrainConfig, train_segmentation

    crop = settings.get("crop")
    cfg = SegTrainConfig(data=data, out=str(out), epochs=train.epochs,
                         batch_size=train.batch_size, lr=train.lr, seed=train.seed, augment=tuple(train.augment),
                         threads=train.threads, max_images=train.max_images, init=init,
                         depth_input=bool(settings.get("depth_input", False)),
                         widths=tuple(settings.get("widths", (16, 24, 48, 64))),
                         backbone=str(settings.get("backbone", "plain")),
                         crop=None if crop is None else (int(crop[0]), int(crop[1])))
    return train_segmentation(cfg, progress=progress, log=lambda _msg: None).model_path


#: Settings of a keypoint checkpoint's ``train`` record that fix its network and targets (kept by the loop).
_KEYPOINT_NET = ("arch", "keypoints", "widths", "decoder", "margin", "dense", "hypotheses", "backbone",
                 "seg_weight", "xyz_weight", "kp_weight", "augment_p", "encoder_lr_scale", "freeze_encoder_bn")


def _train_keypoints(train: LoopTrainConfig, init: str, settings: dict, data: tuple[str, ...], out: Path,
                     progress: bool) -> Path:
    from simtest.training.keypoints import TrainConfig, train_keypoints

    if train.max_images is not None:
        raise ConfigError(f"train config: max_images is for segmentation only; keypoint training reads every "
                          f"image, got max_images = {train.max_images}")
    kept = {k: settings[k] for k in _KEYPOINT_NET if k in settings}
    for k in ("widths", "decoder"):
        if k in kept:
            kept[k] = tuple(int(v) for v in kept[k])
    crop = settings.get("crop")
    cfg = TrainConfig(data=data, out=str(out), epochs=train.epochs, batch_size=train.batch_size, lr=train.lr,
                      seed=train.seed, augment=tuple(train.augment), threads=train.threads, init=init,
                      crop=None if crop is None else (int(crop[0]), int(crop[1])), **kept)
    return train_keypoints(cfg, progress=progress, log=lambda _msg: None).model_path


def _train_arm(train: LoopTrainConfig, entry: Any, init: tuple[str, dict], data: Path, out: Path,
               progress: bool) -> Path:
    """Continue training the estimator's network from the ``init`` checkpoint (path, recorded settings) on the
    original data and ``data``; the new ``model.pt``."""
    init, settings = init
    trainer = _train_keypoints if entry.estimator == "keypoints" else _train_segmentation
    return trainer(train, init, settings, tuple(train.data) + (str(data),), out, progress)


def _evaluate_arm(sweep_cfg: Any, sweep: Path, entry: Any, name: str, checkpoint: Path, out: Path) -> None:
    """Every pose cell of ``name`` in the sweep, run again with ``checkpoint`` on the sweep's data, as cells of
    the sweep folder ``out``."""
    from simtest.evaluation.run import evaluate

    for cdir in sorted((sweep / "cells" / name).iterdir()):
        before = cells.cell_dir(sweep, name, cdir.name, "pose")
        if not cells.is_finished(before):
            continue
        data = cell_dataset(sweep, cdir.name, json.loads((before / "cell.json").read_text()))
        target = cells.cell_dir(out, name, cdir.name, "pose")
        rep = evaluate(data, entry.estimator, split=sweep_cfg.dataset.split, max_images=sweep_cfg.dataset.max_images,
                       progress=False, out_dir=target, vsd=sweep_cfg.vsd,
                       estimator_options={**dict(entry.options), "checkpoint": str(checkpoint)},
                       timeout=sweep_cfg.timeout, overwrite=True, task=sweep_cfg.task)
        cells.finish_cell(target, {"kind": "pose", "estimator": name, "label": name, "dataset": str(data),
                                   "overall": rep.to_json()["overall"], "failures": len(rep.failures)})
    atomic_write_json(out / "sweep_config.json", json.loads((sweep / "sweep_config.json").read_text()))


def _run_arm(fit: AdaptFit, arm: str, train: LoopTrainConfig, init: tuple[str, dict], sweep_cfg: Any, entry: Any,
             progress: bool) -> dict[str, Any]:
    """Generate, train and evaluate one arm; its scores, images and CPU minutes per step."""
    from simtest.generators.config import load_config
    from simtest.generators.pipeline import generate

    out, sweep = fit.out, Path(json.loads((fit.out / "fit.json").read_text())["sweep"])
    cfg = load_config(fit.adapted if arm == "adapted" else fit.uniform)
    cpu: dict[str, float] = {}
    wall: dict[str, float] = {}

    def timed(step: str, call):
        c0, w0 = _cpu_s(), time.perf_counter()
        value = call()
        cpu[step], wall[step] = (_cpu_s() - c0) / 60.0, (time.perf_counter() - w0) / 60.0
        return value

    rep = timed("generate", lambda: generate(cfg, out / "data" / arm, overwrite=True, progress=progress,
                                             command_line=[]))
    model = timed("train", lambda: _train_arm(train, entry, init, out / "data" / arm, out / "train" / arm,
                                              progress))
    timed("evaluate", lambda: _evaluate_arm(sweep_cfg, sweep, entry, fit.estimator, model, out / "sweeps" / arm))
    images = cfg.scenes * cfg.frames_per_scene
    return {"images": images, "frames_written": rep.frames_written, "checkpoint": str(model),
            "cpu_min": cpu, "wall_min": wall, "conditions": condition_scores(read_targets(out / "sweeps" / arm, fit.estimator))}


#: Conditions the adapted config aims at (through the visible fraction): clean images and occlusion levels.
#: Image corruptions, depth noise and other renderers are applied or chosen outside the sampled factors.
_AIMED = re.compile(r"clean|L[0-3]")


def _compare(cond: str, ctl: dict, ada: dict) -> dict[str, Any]:
    """Adapted against control on ``cond``: the gain, the control's 95 % half-width, adapted above it."""
    half = (ctl[cond]["ci95"][1] - ctl[cond]["ci95"][0]) / 2.0
    return {"adapted_minus_control": ada[cond]["score"] - ctl[cond]["score"], "control_ci95_half_width": half,
            "adapted_above_control_interval": bool(ada[cond]["score"] > ctl[cond]["ci95"][1])}


def _verdict(before: dict, arms: dict[str, dict]) -> dict[str, Any]:
    """The weakest condition of the sweep (lowest score before) and the comparison of adapted with control;
    the same for the weakest condition the adapted config aims at (clean or an occlusion level), when the
    weakest is another kind (a corruption, a depth sensor)."""
    weakest = min(before, key=lambda c: (before[c]["score"], c))
    ctl, ada = arms["control"]["conditions"], arms["adapted"]["conditions"]
    main = _compare(weakest, ctl, ada)
    clean_ok = "clean" not in ctl or ada["clean"]["score"] >= ctl["clean"]["ci95"][0]
    aimed = [c for c in before if _AIMED.fullmatch(c)]
    weakest_aimed = min(aimed, key=lambda c: (before[c]["score"], c)) if aimed else None
    return {"weakest_condition": weakest, **main, "clean_within_control_interval": bool(clean_ok),
            "success": bool(main["adapted_above_control_interval"] and clean_ok),
            "weakest_aimed_condition": weakest_aimed,
            "aimed": None if weakest_aimed is None else _compare(weakest_aimed, ctl, ada)}


def _pct(s: dict) -> str:
    return f"{100 * s['score']:.1f} % [{100 * s['ci95'][0]:.1f}, {100 * s['ci95'][1]:.1f}] (n={s['n']})"


def _adapt_md(result: dict[str, Any]) -> str:
    v, arms, before = result["verdict"], result["arms"], result["before"]
    lines = [f"# simtest adapt: {result['estimator']}", "",
             f"Sweep `{result['sweep']}`; {result['images']} new images per arm (seed {result['seed']}); training: "
             f"{result['train']['epochs']} epochs, batch {result['train']['batch_size']}, lr {result['train']['lr']}, "
             f"seed {result['train']['seed']}, from `{result['init']}` on {len(result['train']['data'])} original "
             f"dataset(s) + the arm's images. Score: ADD(-S)-0.1d with its 95 % Wilson interval.", "",
             "| condition | before | control (uniform) | adapted |", "|---|---|---|---|"]
    for cond in before:
        lines.append(f"| {cond} | {_pct(before[cond])} | {_pct(arms['control']['conditions'][cond])} | "
                     f"{_pct(arms['adapted']['conditions'][cond])} |")
    lines += ["", "| arm | images | generate CPU / wall min | train CPU / wall min | evaluate CPU / wall min |",
              "|---|---|---|---|---|"]
    for arm in ARMS:
        c, w = arms[arm]["cpu_min"], arms[arm]["wall_min"]
        lines.append(f"| {arm} | {arms[arm]['images']} | " +
                     " | ".join(f"{c[k]:.2f} / {w[k]:.2f}" for k in ("generate", "train", "evaluate")) + " |")
    lines += ["", f"Weakest condition before: **{v['weakest_condition']}**; adapted - control = "
                  f"{100 * v['adapted_minus_control']:+.1f} points (control's 95 % half-width "
                  f"{100 * v['control_ci95_half_width']:.1f}). Adapted above the control's interval: "
                  f"{'yes' if v['adapted_above_control_interval'] else 'no'}; clean within the control's interval: "
                  f"{'yes' if v['clean_within_control_interval'] else 'no'}.", ""]
    if v.get("aimed") and v["weakest_aimed_condition"] != v["weakest_condition"]:
        a = v["aimed"]
        lines += [f"{v['weakest_condition']} is not a condition the adapted config aims at (only clean images and "
                  f"occlusion levels, through the visible fraction, are). The weakest one it aims at: "
                  f"**{v['weakest_aimed_condition']}**; adapted - control = {100 * a['adapted_minus_control']:+.1f} "
                  f"points (control's 95 % half-width {100 * a['control_ci95_half_width']:.1f}); adapted above the "
                  f"control's interval: {'yes' if a['adapted_above_control_interval'] else 'no'}.", ""]
    return "\n".join(lines)


def run_loop(fit: AdaptFit, train: LoopTrainConfig, *, progress: bool = False) -> dict[str, Any]:
    """Run both arms of the loop for a written fit (:func:`simtest.sweeps.adapt.write_fit`) and write
    ``adapt.json`` and ``adapt.md`` beside it; returns the ``adapt.json`` content.

    Raises:
        ConfigError: The fitted estimator's network cannot be trained here, or the init checkpoint is missing.
    """
    meta = json.loads((fit.out / "fit.json").read_text())
    sweep = Path(meta["sweep"])
    sweep_cfg, entry = _sweep_settings(sweep, fit.estimator)
    start = _init_checkpoint(train, entry, sweep, fit.estimator)
    init = start[0]
    t0 = time.perf_counter()
    arms = {arm: _run_arm(fit, arm, train, start, sweep_cfg, entry, progress) for arm in ARMS}
    before = condition_scores(read_targets(sweep, fit.estimator))
    result = {"sweep": str(sweep), "estimator": fit.estimator, "images": meta["images"], "seed": meta["seed"],
              "init": init, "train": asdict(train), "before": before, "arms": arms,
              "verdict": _verdict(before, arms), "wall_s": time.perf_counter() - t0}
    atomic_write_json(fit.out / "adapt.json", result)
    atomic_write_text(fit.out / "adapt.md", _adapt_md(result))
    return result
