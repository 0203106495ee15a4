"""``simtest adapt``: a finished sweep tells the generator where to spend the next images.

:func:`write_fit` reads one estimator's per-target results of a sweep folder
(:mod:`simtest.sweeps.adapt_targets`), fits the sampler (:mod:`simtest.sweeps.adapt_fit`) and writes into
``OUT``:

* ``adapted.toml``: the sweep's generation config with the fitted weights, ``images`` images and a new seed
  (``simtest generate --config OUT/adapted.toml --out DIR`` makes the dataset; edit it freely);
* ``uniform.toml``: the control, the same config, images and seed without weights;
* ``fit.json`` / ``fit.md``: per factor and bin the targets, failures, failure rate with its 95 % interval, the
  uniform and the adapted mass, and the rule;
* ``mass.png``: uniform vs adapted mass per factor (:mod:`simtest.sweeps.adapt_plot`).

This is an orchestration module: the generation config is imported lazily.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from simtest.errors import ConfigError, DatasetError
from simtest.io.files import atomic_write_json, atomic_write_text
from simtest.sweeps.adapt_fit import DEFAULT_BINS, DEFAULT_FLOOR, FactorFit, adapted_config, fit_sampler, uniform_config
from simtest.sweeps.adapt_targets import FAIL_THRESHOLD, read_targets, sweep_estimators

__all__ = ["AdaptFit", "write_fit", "sweep_generate_config", "choose_estimator", "RULE"]

#: The mass rule as written into fit.json and fit.md.
RULE = ("mass = floor / B + (1 - floor) * low / sum(low); low = lower end of the bin's 95 % Wilson interval of "
        "the failure rate, B = bins of the factor; uniform when every low is 0")


@dataclass(frozen=True)
class AdaptFit:
    """What :func:`write_fit` wrote: the folder, the estimator fitted, the files and the fits."""

    out: Path
    estimator: str
    adapted: Path
    uniform: Path
    fits: tuple[FactorFit, ...]
    targets: int


def choose_estimator(sweep_dir: str | Path, estimator: str | None) -> str:
    """``estimator``, or the sweep's only one; several without a choice is an error naming them."""
    names = sweep_estimators(sweep_dir)
    if estimator is not None:
        if estimator not in names:
            raise ConfigError(f"--estimator {estimator!r} is not in the sweep {str(sweep_dir)!r}; its estimators: "
                              f"{names}")
        return estimator
    if len(names) != 1:
        raise ConfigError(f"the sweep {str(sweep_dir)!r} has the estimators {names}; choose one with --estimator")
    return names[0]


def sweep_generate_config(sweep_dir: str | Path):
    """The generation config of a sweep's clean dataset (its ``[dataset.generate]`` or the dataset's manifest).

    Raises:
        DatasetError: No ``sweep_config.json`` in ``sweep_dir``.
    """
    from simtest.sweeps.grid import SweepConfig
    from simtest.sweeps.renders import clean_generate_config

    path = Path(sweep_dir) / "sweep_config.json"
    if not path.is_file():
        raise DatasetError(f"{str(sweep_dir)!r} has no sweep_config.json: not a sweep folder")
    cfg = SweepConfig.from_dict(json.loads(path.read_text()), source=str(path))
    clean = Path(cfg.dataset.path) if cfg.dataset.path is not None else Path(sweep_dir) / "data" / "clean"
    return clean_generate_config(cfg, clean).replace(workers=1, backend="local", ray_address=None)


def _header(fits: tuple[FactorFit, ...], estimator: str, sweep: Path, what: str) -> str:
    lines = [f"# {what} (simtest adapt) from the sweep {sweep} for estimator {estimator!r}.",
             f"# Rule: {RULE}.", "# Fitted masses per factor (bins in order; docs/adapt.md):"]
    for fit in fits:
        aim = fit.factor.weights or "not generated"
        lines.append(f"#   {fit.factor.name} -> {aim}: " + ", ".join(f"{b.label} {b.mass:.3f}" for b in fit.bins))
    return "\n".join(lines) + "\n"


def _fit_md(fits: tuple[FactorFit, ...], estimator: str, n: int, floor: float) -> str:
    out = [f"# Fitted sampler: {estimator}", "",
           f"{n} targets; a target fails when unmatched or ADD(-S) > {FAIL_THRESHOLD:g} d. Rule: {RULE}; "
           f"floor = {floor:g}.", ""]
    for fit in fits:
        unit = f" ({fit.factor.unit})" if fit.factor.unit else ""
        out += [f"## {fit.factor.name}{unit} -> {fit.factor.weights or 'not generated (report only)'}", "",
                "| bin | targets | failures | failure rate (95 %) | uniform | adapted |", "|---|---|---|---|---|---|"]
        for b in fit.bins:
            rate = "n/a" if not b.n else f"{100 * b.rate:.1f} % [{100 * b.ci_low:.1f}, {100 * b.ci_high:.1f}]"
            out.append(f"| {b.label} | {b.n} | {b.failures} | {rate} | {b.uniform:.3f} | {b.mass:.3f} |")
        out.append("")
    return "\n".join(out)


def write_fit(sweep_dir: str | Path, out: str | Path, images: int, estimator: str | None = None, *,
              bins: int = DEFAULT_BINS, floor: float = DEFAULT_FLOOR, seed: int | None = None) -> AdaptFit:
    """Fit the sampler on a sweep and write the adapted and uniform configs, ``fit.json``, ``fit.md`` and
    ``mass.png`` into ``out`` (created).

    Args:
        sweep_dir: A finished sweep folder.
        out: Output folder.
        images: Images of the adapted (and the control) dataset; ``scenes`` is rounded up to whole scenes.
        estimator: The sweep's estimator to fit (None: its only one).
        bins: Parts of each numeric factor's range.
        floor: The rule's floor, in (0, 1].
        seed: Seed of both new datasets (None: the sweep dataset's seed + 1, so the new scenes are not its own).

    Raises:
        ConfigError: ``images < 1``, bad ``bins`` / ``floor``, an unknown estimator.
        DatasetError: Not a finished sweep folder.
    """
    from simtest.sweeps.adapt_plot import mass_figure

    if images < 1 or bins < 1 or not 0.0 < floor <= 1.0:
        raise ConfigError(f"need images >= 1, bins >= 1 and floor in (0, 1], got images={images!r}, bins={bins!r}, "
                          f"floor={floor!r}")
    sweep = Path(sweep_dir).resolve()
    name = choose_estimator(sweep, estimator)
    base = sweep_generate_config(sweep)
    targets = read_targets(sweep, name)
    fits = tuple(fit_sampler(targets, base, bins, floor))
    seed = base.seed + 1 if seed is None else int(seed)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    adapted, uniform = out / "adapted.toml", out / "uniform.toml"
    atomic_write_text(adapted, _header(fits, name, sweep, "Adapted generation config") +
                      adapted_config(base, fits, images, seed).to_toml())
    atomic_write_text(uniform, _header(fits, name, sweep, "Uniform control config (the same without weights)") +
                      uniform_config(base, images, seed).to_toml())
    atomic_write_json(out / "fit.json", {"sweep": str(sweep), "estimator": name, "targets": len(targets),
                                         "images": images, "seed": seed, "bins": bins, "floor": floor, "rule": RULE,
                                         "fail_threshold_diameter": FAIL_THRESHOLD,
                                         "factors": [f.to_dict() for f in fits]})
    atomic_write_text(out / "fit.md", _fit_md(fits, name, len(targets), floor))
    mass_figure(fits, out / "mass.png", f"{name}: uniform vs adapted sampling mass ({len(targets)} targets)")
    return AdaptFit(out, name, adapted, uniform, fits, len(targets))
