"""The figure of ``simtest adapt``: per factor, the uniform and the adapted sampling mass of each bin (bars),
with the bin's failure rate and its 95 % Wilson interval (points with error bars, right axis) and the target
count under each bin (matplotlib, Agg)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

from simtest.sweeps.adapt_fit import FactorFit

__all__ = ["mass_figure"]


def mass_figure(fits: Sequence[FactorFit], path: str | Path, title: str = "") -> Path:
    """Write the figure of ``fits`` (one panel per factor) as a PNG at ``path``; returns ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    cols = 2
    rows = math.ceil(len(fits) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(11.0, 2.9 * rows), squeeze=False)
    for ax, fit in zip(axes.ravel(), fits):
        x = np.arange(len(fit.bins))
        ax.bar(x - 0.2, [b.uniform for b in fit.bins], 0.4, color="#b0b0b0", label="uniform mass")
        ax.bar(x + 0.2, [b.mass for b in fit.bins], 0.4, color="#3070b0", label="adapted mass")
        ax.set_xticks(x, [f"{b.label}\nn={b.n}" for b in fit.bins], fontsize=7)
        ax.set_ylabel("mass", fontsize=8)
        unit = f" ({fit.factor.unit})" if fit.factor.unit else ""
        aim = fit.factor.weights or "not generated: report only"
        ax.set_title(f"{fit.factor.name}{unit} -> {aim}", fontsize=8)
        twin = ax.twinx()
        rate = [b.rate if b.n else np.nan for b in fit.bins]
        err = [[b.rate - b.ci_low if b.n else 0 for b in fit.bins], [b.ci_high - b.rate if b.n else 0 for b in fit.bins]]
        twin.errorbar(x, rate, yerr=err, fmt="o", color="#c03030", ms=4, capsize=3, label="failure rate (95 %)")
        twin.set_ylim(0, 1.05)
        twin.set_ylabel("failure rate", fontsize=8, color="#c03030")
        if ax is axes.ravel()[0]:
            h1, l1 = ax.get_legend_handles_labels()
            h2, l2 = twin.get_legend_handles_labels()
            fig.legend(h1 + h2, l1 + l2, fontsize=8, frameon=False, loc="lower center", ncol=3)
    for ax in axes.ravel()[len(fits):]:
        ax.axis("off")
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout(rect=(0.0, 0.04, 1.0, 1.0))
    path = Path(path)
    fig.savefig(path, format="png", dpi=90)
    plt.close(fig)
    return path
