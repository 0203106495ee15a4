"""The metric registry is the one list of metrics: everything computed is registered, and formats are right."""

from __future__ import annotations

import ast
import math
from pathlib import Path

import pytest

from simtest.evaluation.run import METRIC_DEFINITIONS
from simtest.evaluation.scoring import aggregate as _aggregate
from simtest.metrics.registry import METRICS, metric, metric_keys
from simtest.sweeps.grid import SweepConfig
from simtest.evaluation.tables import SUMMARY_METRICS, TABLE_METRICS

ROOT = Path(__file__).resolve().parents[3]


def _rows() -> list[dict]:
    return [
        {"matched": True, "adi": 0.004, "add_s_or_add": 0.004, "diameter_m": 0.1, "re_sym": 3.0, "te": 0.01},
        {"matched": False, "adi": 0.0, "add_s_or_add": 0.0, "diameter_m": 0.1, "re_sym": 0.0, "te": 0.0},
    ]


def test_every_aggregate_is_registered():
    agg = _aggregate(_rows())
    keys = set(agg) - {"ci95"}  # ci95: the 95 % intervals, keyed by registered proportions
    assert keys <= set(metric_keys()), sorted(keys - set(metric_keys()))
    assert set(agg["ci95"]) <= keys and all(0.0 <= lo <= agg[k] <= hi <= 1.0 for k, (lo, hi) in agg["ci95"].items())
    for k in ("ar", "ar_vsd", "ar_mssd", "ar_mspd", "num_estimates", "num_failures", "mean_time_per_image_s"):
        metric(k)


def test_tables_and_definitions_read_the_registry():
    assert set(TABLE_METRICS) <= set(metric_keys()) and set(SUMMARY_METRICS) <= set(metric_keys())
    assert all(m.key in METRIC_DEFINITIONS for m in METRICS)
    assert len({m.key for m in METRICS}) == len(METRICS)


def test_aggregates_by_hand():
    out = _aggregate(_rows())
    assert out["num_targets"] == 2 and out["num_matched"] == 1
    assert out["add_s_or_add_01d"] == 0.5 and out["adds_lt_2cm"] == 0.5
    assert out["median_re_deg"] == pytest.approx((3.0 + 180.0) / 2)


def test_formats():
    assert metric("add_s_or_add_01d").format(0.1234) == "12.3"
    assert metric("median_te_m").format(0.01234) == "1.23"
    assert metric("median_re_deg").format(math.inf) == "inf"
    assert metric("ar").format(float("nan")) == "–" and metric("ar").format(None) == "–"
    assert metric("num_targets").format(42) == "42"
    assert metric("median_re_deg").header == "MedErr [deg]" and metric("num_targets").header == "N"
    assert metric("acc_pi_6").higher_is_better and not metric("median_re_deg").higher_is_better


def test_unknown_metric_lists_the_known_ones():
    with pytest.raises(KeyError, match="registered: num_targets"):
        metric("add_001d")


def test_sweep_accepts_exactly_the_sweepable_metrics():
    base = {"estimators": [{"name": "o", "estimator": "oracle"}], "dataset": {"path": "x"}}
    SweepConfig.from_dict({**base, "metrics": list(metric_keys(sweepable=True))})
    with pytest.raises(ValueError, match="num_targets"):
        SweepConfig.from_dict({**base, "metrics": ["num_targets"]})


def _imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text())
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module:
            out.add(node.module)
        elif isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
    return out


def test_report_only_reads_the_sweep_tables():
    assert not {m for m in _imports(ROOT / "simtest" / "sweeps" / "report.py") if m.startswith("simtest.sweeps.grid")}
    assert not {m for m in _imports(ROOT / "simtest" / "sweeps" / "cells.py") if m.startswith(("simtest.sweeps.grid",
                                                                                     "simtest.sweeps.report"))}
