"""Robustness sweeps: estimators x conditions (occlusion levels, image corruptions, depth noise, render
profiles, depth sensors) -> pose metrics and grasp success, cached per cell so an interrupted sweep resumes
without recomputing.

A *condition* changes one factor at a time from the clean data (the classic robustness-table layout):
``clean``, ``L1``..``L3`` (2D paste occlusion: object cutouts by default), ``<corruption>-<severity>`` (e.g.
``fog-4``), ``depth-<preset>`` (image-space depth noise); and the generation conditions
(:mod:`simtest.sweeps.renders`): ``depth-<sensor>`` (a simulated depth sensor, e.g. ``depth-d435-stereo``) and
render conditions (``factors.renderers`` profiles, named ``[[renders]]`` override sets), whose datasets are the
clean scenes generated again with the same ground truth. A *cell* is (estimator, condition, kind) with kind
``pose`` (evaluation on the condition's dataset) or ``grasp`` (closed-loop episodes with the same condition
applied to the wrist observations; occlusion is physical there; generation conditions have no grasp cells).
Each finished cell writes ``cells/<estimator>/<condition>/<kind>/cell.json`` last; a resumed sweep skips
every cell that has it.

Where it runs (:mod:`simtest.backend`): the sweep goes in three phases, each a set of units on the chosen back
end: the datasets generated (the clean one, then each generation condition's: ``generate``, one unit per
scene), the corrupted copies it needs (one unit per condition), then the cells (one unit per cell; a cell runs
its own evaluation or episodes in its process, with one worker). ``workers`` is the number of units run at once (local processes, or the CPUs of a Ray instance
started here). A cell's numbers do not depend on where it ran: episodes and images are seeded by their index.

This is an orchestration module: it drives :mod:`simtest.generators`, :mod:`simtest.evaluation.run` and
:mod:`simtest.envs` (imported lazily).
"""

from __future__ import annotations

import dataclasses
import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any


from simtest.sweeps import cells
from simtest.sweeps.renders import RenderEntry
from simtest.backend import RUN_FIELDS, Backend, BackendError, RunStats, check_backend, preflight, run_units, session
from simtest.errors import ConfigError, DatasetError
from simtest.estimators.base import GT_MASKS_LABEL
from simtest.estimators.guard import DEFAULT_TIMEOUT_S
from simtest.io.bop import dataset_split_dir
from simtest.io.files import atomic_write_json, jsonable, prepare_out_dir
from simtest.metrics.registry import metric_keys
from simtest.schema import bounds, build, config_changes, read_config_file, to_plain

__all__ = ["SweepConfig", "EstimatorEntry", "Condition", "SweepReport", "load_sweep_config", "run_sweep",
           "conditions_of"]

@dataclass(frozen=True)
class EstimatorEntry:
    """One estimator of the sweep: a table label, a registered name or ``module:attr``, and options."""

    name: str
    estimator: str
    options: dict = field(default_factory=dict)


@dataclass(frozen=True)
class DatasetSection:
    """Evaluate on an existing BOP dataset (``path``) or generate one (``generate``: generation-config
    values, as in ``simtest generate --print-config``)."""

    path: str | None = None
    generate: dict | None = None
    split: str | None = None  # None: the dataset's only split
    max_images: int | None = field(default=None, metadata=bounds(1, 10_000_000))


@dataclass(frozen=True)
class FactorsSection:
    """The conditions beside ``clean``: exactly those listed (a factor left out adds no condition)."""

    occlusion: tuple[str, ...] = ()
    occlusion_definition: str = field(default="pascal3d+", metadata=bounds(choices=("pascal3d+", "objectcentric")))
    corruptions: tuple[str, ...] = ()
    severities: tuple[int, ...] = (4,)
    depth_noise: tuple[str, ...] = ()
    # 2D paste occluders of L1..L3: cutouts of the dataset's own unoccluded objects, or procedural noise shapes
    occlusion_kind: str = field(default="objects", metadata=bounds(choices=("objects", "paste")))
    # generation conditions (the clean scenes generated again): render profiles and simulated depth sensors
    renderers: tuple[str, ...] = ()
    depth_sensors: tuple[str, ...] = ()


@dataclass(frozen=True)
class GraspSection:
    """Closed-loop grasping per (estimator, condition); ``episodes = 0`` skips it."""

    episodes: int = field(default=0, metadata=bounds(0, 100_000))
    objects: str = "builtin-small"
    units: str = field(default="auto", metadata=bounds(choices=("m", "cm", "mm", "auto")))  # of mesh files
    scale: float = field(default=1.0, metadata=bounds(1e-6, 1e6))  # times the units: metres per file unit
    targets: tuple[str, ...] = ()
    width: int = field(default=320, metadata=bounds(32, 4096))
    height: int = field(default=240, metadata=bounds(24, 4096))
    n_distractors: int = field(default=0, metadata=bounds(0, 20))


@dataclass(frozen=True)
class SweepConfig:
    """A whole sweep. ``metrics`` lists sweepable keys of :mod:`simtest.metrics.registry` shown in the tables
    and report (``ap``, ``cls_acc`` ... need ``task = "detection"``: BOP24, estimators told nothing);
    ``timeout`` is the time limit of one estimator call (per image, per grasp episode), seconds (0: none);
    ``renders`` are named generation-config override sets, each a render condition."""

    estimators: tuple[EstimatorEntry, ...]
    dataset: DatasetSection = field(default_factory=DatasetSection)
    factors: FactorsSection = field(default_factory=FactorsSection)
    grasp: GraspSection = field(default_factory=GraspSection)
    metrics: tuple[str, ...] = ("add_s_or_add_01d", "ar", "acc_pi_6")
    task: str = field(default="localization", metadata=bounds(choices=("localization", "detection")))
    vsd: bool = False
    seed: int = field(default=0, metadata=bounds(0, 2**63 - 1))
    workers: int = field(default=1, metadata=bounds(1, 64))
    timeout: float = field(default=DEFAULT_TIMEOUT_S, metadata=bounds(0, 86_400))
    backend: str = field(default="local", metadata=bounds(choices=("local", "ray")))  # where units run
    ray_address: str | None = None  # with backend "ray": "auto" or HOST:PORT of a running cluster
    renders: tuple[RenderEntry, ...] = ()

    @staticmethod
    def from_dict(data: dict[str, Any], source: str = "sweep config") -> "SweepConfig":
        if "estimators" not in data:
            raise ConfigError(f"{source}: 'estimators' is missing; add at least one [[estimators]] table with "
                              f"name and estimator (e.g. name = \"icp\", estimator = \"icp\")")
        cfg = build(SweepConfig, data, prefix="", source=source)
        cfg.validate(source)
        return cfg

    def validate(self, source: str) -> None:
        from simtest.corrupt import CORRUPTIONS, DEPTH_PRESETS
        from simtest.estimators import ESTIMATORS

        def bad(key: str, value: Any, allowed: Any) -> ConfigError:
            return ConfigError(f"{source}: {key} = {value!r} is invalid; allowed: {allowed}")

        if not self.estimators:
            raise bad("estimators", [], "at least one [[estimators]] table")
        names = [e.name for e in self.estimators]
        if len(set(names)) != len(names):
            raise bad("estimators[].name", names, "unique names")
        for i, e in enumerate(self.estimators):
            if e.estimator not in ESTIMATORS and ":" not in e.estimator:
                raise bad(f"estimators[{i}].estimator", e.estimator,
                          f"{' | '.join(sorted(ESTIMATORS))} or 'module:attr'")
            if not e.name or "/" in e.name:
                raise bad(f"estimators[{i}].name", e.name, "a non-empty label without '/'")
        if (self.dataset.path is None) == (self.dataset.generate is None):
            raise ConfigError(f"{source}: [dataset] needs exactly one of path = \"DIR\" or a [dataset.generate] "
                              f"table")
        for lv in self.factors.occlusion:
            if lv not in ("L1", "L2", "L3"):
                raise bad("factors.occlusion", lv, "'L1' | 'L2' | 'L3' (L0 is the clean condition)")
        for c in self.factors.corruptions:
            if c not in CORRUPTIONS:
                raise bad("factors.corruptions", c, " | ".join(CORRUPTIONS))
        for s in self.factors.severities:
            if s not in (1, 2, 3, 4, 5):
                raise bad("factors.severities", s, "1 | 2 | 3 | 4 | 5")
        for d in self.factors.depth_noise:
            if d not in DEPTH_PRESETS:
                raise bad("factors.depth_noise", d, " | ".join(DEPTH_PRESETS))
        self._validate_generation_conditions(source, bad)
        allowed = metric_keys(sweepable=True)
        for m in self.metrics:
            if m not in allowed:
                raise bad("metrics", m, " | ".join(allowed))
        try:
            check_backend(self.backend, self.ray_address, self.workers)
        except ConfigError as exc:
            raise ConfigError(f"{source}: {exc}") from None

    def _validate_generation_conditions(self, source: str, bad) -> None:
        from simtest.sweeps.renders import DEPTH_SENSORS, PROFILES, check_overrides, flatten_overrides

        for r in self.factors.renderers:
            if r not in PROFILES:
                raise bad("factors.renderers", r, " | ".join(PROFILES))
        for d in self.factors.depth_sensors:
            if d not in DEPTH_SENSORS:
                raise bad("factors.depth_sensors", d, " | ".join(DEPTH_SENSORS))
        for i, r in enumerate(self.renders):
            if not r.overrides:
                raise bad(f"renders[{i}].overrides", {}, "a table of generation-config overrides, e.g. "
                                                         "{ \"render.profile\" = \"pbr\" }")
            check_overrides(flatten_overrides(r.overrides), f"{source}: renders[{i}].overrides")
        names = [c.name for c in conditions_of(self)]
        for i, r in enumerate(self.renders):
            if not r.name or "/" in r.name or r.name.startswith("."):
                raise bad(f"renders[{i}].name", r.name, "a non-empty label without '/' or a leading '.'")
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise bad("renders[].name", dup[0], f"a condition name not taken by another condition "
                                                f"({', '.join(names)})")

    def to_dict(self) -> dict[str, Any]:
        return to_plain(dataclasses.asdict(self))


#: The sweep ``simtest demo`` runs (also in the repository as configs/sweep-demo.toml).
DEMO_SWEEP: dict[str, Any] = {
    "seed": 0,
    "metrics": ["add_s_or_add_01d", "ar", "acc_pi_6"],
    "estimators": [
        {"name": "oracle-5deg-5mm", "estimator": "oracle", "options": {"rot_noise_deg": 5.0, "trans_noise_mm": 5.0}},
        {"name": "oracle-15deg-25mm", "estimator": "oracle",
         "options": {"rot_noise_deg": 15.0, "trans_noise_mm": 25.0}},
        {"name": "icp", "estimator": "icp"},
        {"name": "segicp", "estimator": "segicp"},
    ],
    "dataset": {"generate": {"objects": "builtin-small", "scenes": 3, "frames_per_scene": 3,
                             "camera": {"width": 320, "height": 240}}},
    "factors": {"occlusion": ["L1", "L2", "L3"], "corruptions": ["brightness", "frost", "snow", "fog"],
                "severities": [4], "depth_noise": ["realsense-d435"]},
    "grasp": {"episodes": 3, "objects": "builtin-small", "width": 160, "height": 120},
}


def load_sweep_config(path: str | Path) -> SweepConfig:
    """Read and validate a TOML or JSON sweep config."""
    return SweepConfig.from_dict(read_config_file(path), source=str(path))


# ---------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Condition:
    """One column of the robustness table."""

    name: str
    factor: str  # "clean" | "occlusion" | "corruption" | "depth" | "sensor" | "render"
    level: str  # "L2", "fog", "realsense-d435", "d435-stereo", "pbr", "render.profile=pbr;render.pbr_spp=4" ...
    severity: int | None = None
    overrides: dict = field(default_factory=dict)  # generation-config overrides ("sensor" and "render")

    @property
    def generated(self) -> bool:
        """Whether the condition's dataset is generated again (render and depth-sensor conditions)."""
        return self.factor in ("sensor", "render")

    def corruption_spec(self, definition: str, kind: str = "objects"):
        """The image-space corruption of the condition (None for clean and generated conditions); ``kind``
        is the 2D occlusion kind (``objects`` | ``paste``, :data:`simtest.corrupt.OCCLUSION_KINDS`)."""
        from simtest.corrupt import CorruptionSpec

        if self.factor == "occlusion":
            return CorruptionSpec(occlusion=self.level, occlusion_kind=kind, occlusion_definition=definition)
        if self.factor == "corruption":
            return CorruptionSpec(weather=self.level, severity=self.severity)
        if self.factor == "depth":
            return CorruptionSpec(depth_noise=self.level)
        return None

    def grasp_settings(self) -> dict[str, Any]:
        if self.factor == "occlusion":
            return {"occlusion": self.level}
        if self.factor == "corruption":
            return {"weather": self.level, "severity": self.severity}
        if self.factor == "depth":
            return {"depth_noise": self.level}
        return {}


def conditions_of(cfg: SweepConfig) -> list[Condition]:
    """The clean condition, then occlusion levels, corruption x severity, depth presets, depth sensors
    (``depth-<sensor>``), render profiles (named by the profile) and ``[[renders]]`` (table order)."""
    from simtest.sweeps.renders import flatten_overrides, overrides_text

    out = [Condition("clean", "clean", "L0")]
    out += [Condition(lv, "occlusion", lv) for lv in cfg.factors.occlusion]
    out += [Condition(f"{c}-{s}", "corruption", c, s) for c in cfg.factors.corruptions for s in cfg.factors.severities]
    out += [Condition(f"depth-{d}", "depth", d) for d in cfg.factors.depth_noise]
    out += [Condition(f"depth-{d}", "sensor", d, overrides={"render.depth_sensor": d})
            for d in cfg.factors.depth_sensors]
    out += [Condition(p, "render", p, overrides={"render.profile": p}) for p in cfg.factors.renderers]
    for r in cfg.renders:
        ov = flatten_overrides(r.overrides)
        out.append(Condition(r.name, "render", overrides_text(ov), overrides=ov))
    return out


@dataclass
class SweepReport:
    out_dir: Path
    cells_run: list[str] = field(default_factory=list)
    cells_skipped: list[str] = field(default_factory=list)
    seconds: float = 0.0
    paths: dict[str, Path] = field(default_factory=dict)
    run: RunStats = field(default_factory=RunStats)  # what the back end did (units retried, lost)


def _prepare_dataset(cfg: SweepConfig, out: Path, progress: bool) -> Path:
    if cfg.dataset.path is not None:
        path = Path(cfg.dataset.path).resolve()
        dataset_split_dir(path, cfg.dataset.split)  # the split exists (or the only one is found), else a clear error
        return path
    from simtest.generators.pipeline import generate
    from simtest.sweeps.renders import clean_generate_config

    gen = clean_generate_config(cfg, out / "data" / "clean")
    path = out / "data" / "clean"
    done = path / "manifest.json"
    if done.exists():
        generate(gen, path, resume=True, progress=progress)
    else:
        generate(gen, path, overwrite=True, progress=progress)
    return path


def _corrupt_unit(unit: tuple[str, str, Condition, str, str, int]) -> str:
    """One corrupted copy of the clean dataset (a unit of work): ``(clean, out, condition, occlusion definition,
    occlusion kind, seed)``."""
    from simtest.corrupt import corrupt_dataset

    clean, path, cond, definition, kind, seed = unit
    corrupt_dataset(clean, path, cond.corruption_spec(definition, kind), seed=seed, overwrite=True, progress=False)
    return path


def _condition_datasets(cfg: SweepConfig, conds: list[Condition], out: Path, stats: RunStats) -> dict[str, Path]:
    """The dataset of every condition in ``conds`` (``{name: folder}``): the clean one, generated unless given,
    the generation conditions' (generated, each checked to hold the clean ground truth), and the corrupted
    copies not made yet (one unit each on the sweep's back end)."""
    clean = _prepare_dataset(cfg, out, progress=False)
    found = {c.name: clean if c.factor == "clean" else out / "data" / c.name for c in conds}
    generated = [c for c in conds if c.generated]
    if generated:
        from simtest.sweeps.renders import clean_generate_config, condition_generate_config, prepare_condition_dataset

        clean_gen = clean_generate_config(cfg, clean)
        gens = {c.name: condition_generate_config(clean_gen, c.overrides, c.name) for c in generated}
        for c in generated:  # every override is applied before anything is generated
            found[c.name] = prepare_condition_dataset(clean_gen, clean, gens[c.name], c.name, found[c.name],
                                                      progress=False)
    todo = [(str(clean), str(found[c.name]), c, cfg.factors.occlusion_definition, cfg.factors.occlusion_kind,
             cfg.seed) for c in conds
            if c.factor not in ("clean", "sensor", "render") and not (found[c.name] / "corruption.json").exists()]
    for _ in run_units(_corrupt_unit, todo, Backend.of(cfg), stats=stats):
        pass
    return found


def _cell_unit(unit: tuple[dict, int, Condition, str, str, str | None]) -> str:
    """One cell (a unit of work): ``(sweep config, estimator index, condition, kind, cell folder, dataset)``;
    returns its key. The cell runs its episodes or images in this process."""
    cfg_dict, e, cond, kind, cdir, data = unit
    cfg = SweepConfig.from_dict(cfg_dict)
    est = cfg.estimators[e]
    if kind == "pose":
        _run_pose_cell(cfg, est, Path(data), Path(cdir))
    else:
        _run_grasp_cell(cfg, est, cond, Path(cdir))
    return f"{est.name}/{cond.name}/{kind}"


def run_sweep(cfg: SweepConfig, out_dir: str | Path, *, resume: bool = False, overwrite: bool = False,
              progress: bool = True) -> SweepReport:
    """Run every cell of the sweep and write ``results.csv``, ``summary.csv``, ``tables.md``, ``report.html``.

    Args:
        cfg: Validated sweep config.
        out_dir: Output folder; must be empty/absent unless ``resume`` or ``overwrite``.
        resume: Keep finished cells (those with ``cell.json``) and compute the rest.
        overwrite: Delete ``out_dir`` first.
        progress: Progress bar over the whole grid.

    Raises:
        DatasetError: Non-empty ``out_dir`` without ``resume``/``overwrite``, or a resume with another config.
        BackendError: Cells lost with their workers beyond the retries (``--resume`` computes them).
    """
    from tqdm import tqdm

    out = Path(out_dir).resolve()  # absolute: a worker's working folder may differ
    preflight(Backend.of(cfg))  # before the output is touched
    _check_sweep_folder(cfg, out, resume, overwrite)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(out / "sweep_config.json", cfg.to_dict())
    t0 = time.perf_counter()
    report = SweepReport(out)
    conds = conditions_of(cfg)
    kinds = ["pose"] + (["grasp"] if cfg.grasp.episodes > 0 else [])
    grid = [(e, c, k) for c in conds for e in range(len(cfg.estimators)) for k in kinds
            if k == "pose" or not c.generated]  # the grasp scene renders with its own renderer
    todo = []
    for e, cond, kind in grid:
        cdir = cells.cell_dir(out, cfg.estimators[e].name, cond.name, kind)
        if cells.is_finished(cdir):
            report.cells_skipped.append(f"{cfg.estimators[e].name}/{cond.name}/{kind}")
        else:
            todo.append((e, cond, kind, cdir))
    bar = tqdm(total=len(grid), initial=len(report.cells_skipped), unit="cell", desc="sweep",
               disable=not progress, dynamic_ncols=True)
    started = RunStats()
    try:
        with session(Backend.of(cfg), started):
            pose_conds = list({c.name: c for _, c, k, _ in todo if k == "pose"}.values())
            data = _condition_datasets(cfg, pose_conds, out, report.run) if pose_conds else {}
            units = [(cfg.to_dict(), e, c, k, str(d), str(data[c.name]) if k == "pose" else None)
                     for e, c, k, d in todo]
            for key in run_units(_cell_unit, units, Backend.of(cfg), stats=report.run):
                report.cells_run.append(key)
                bar.update(1)
    except BackendError as exc:
        if not report.run.failures:
            raise
        raise BackendError(f"{exc}; the finished cells are kept: run the same command with --resume to compute "
                           f"the rest") from exc
    finally:
        bar.close()
        report.run.startup_s = max(report.run.startup_s, started.startup_s)
    from simtest.sweeps.report import write_report

    report.paths = cells.write_tables(out, [e.name for e in cfg.estimators], conds)
    report.paths.update(write_report(cfg, out, conds))
    report.seconds = time.perf_counter() - t0
    return report


def _check_sweep_folder(cfg: SweepConfig, out: Path, resume: bool, overwrite: bool) -> None:
    """The output-folder rule, and on resume: the recorded config must match (where it runs aside)."""
    protect = [] if cfg.dataset.path is None else [cfg.dataset.path]
    if not prepare_out_dir(out, overwrite=overwrite, resume=resume, can_resume=True, clear=True, protect=protect,
                           what="sweep folder"):
        return
    old = out / "sweep_config.json"
    if not old.is_file():
        raise DatasetError(f"cannot resume {str(out)!r}: it has no sweep_config.json (not a sweep folder); "
                           f"choose another --out or pass --overwrite")
    defaults = to_plain(dataclasses.asdict(SweepConfig(estimators=())))
    diffs = config_changes(json.loads(old.read_text()), cfg.to_dict(), defaults, ignore=RUN_FIELDS)
    if diffs:
        raise DatasetError(f"cannot resume {str(out)!r}: it was run with another config at "
                           f"{', '.join(diffs[:8])} (see {old}); use the same config or --overwrite")


def _run_pose_cell(cfg: SweepConfig, est: EstimatorEntry, data: Path, cdir: Path) -> None:
    from simtest.evaluation.run import evaluate

    t0 = time.perf_counter()
    # The cell folder is the sweep's own: a killed cell's leftovers are replaced.
    rep = evaluate(data, est.estimator, split=cfg.dataset.split, max_images=cfg.dataset.max_images,
                   progress=False, out_dir=cdir, vsd=cfg.vsd, estimator_options=dict(est.options),
                   timeout=cfg.timeout, overwrite=True, task=cfg.task)
    label = est.name + (GT_MASKS_LABEL if rep.settings.get("gt_masks") else "")
    cells.finish_cell(cdir, {"kind": "pose", "estimator": est.name, "label": label, "dataset": str(data),
                             "overall": rep.to_json()["overall"], "seconds": time.perf_counter() - t0,
                             "failures": len(rep.failures)})


def _run_grasp_cell(cfg: SweepConfig, est: EstimatorEntry, cond: Condition, cdir: Path) -> None:
    from simtest.envs.runner import GraspRunConfig, run_grasp_episodes

    t0 = time.perf_counter()
    g = cfg.grasp
    # one worker: the cell is the unit of work, and the sweep's workers run cells side by side
    run = GraspRunConfig(estimator=est.estimator, estimator_options=dict(est.options), episodes=g.episodes,
                         seed=cfg.seed, objects=g.objects, units=g.units, scale=g.scale,
                         targets=tuple(g.targets), n_distractors=g.n_distractors,
                         width=g.width, height=g.height, workers=1, timeout=cfg.timeout,
                         **cond.grasp_settings())
    rep = run_grasp_episodes(run, cdir, progress=False, overwrite=True)
    cells.finish_cell(cdir, {"kind": "grasp", "estimator": est.name, "summary": jsonable(rep.summary),
                             "seconds": time.perf_counter() - t0})
