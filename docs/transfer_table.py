"""The transfer table: segicp trained on fast, on pbr and on a mixture, tested on every profile and on unseen looks.

Run from the repository root (needs the pbr and train extras)::

    python docs/transfer_table.py --out /tmp/transfer            # the README's table (about 75 min on 2 cores)
    python docs/transfer_table.py --out /tmp/t --small           # the same steps at toy size (minutes)

Every model sees the same scenes, the same number of images and the same optimisation steps; only the renderer of
its training images differs. The training scenes are two seeded sets, A (70 % of the images) and B (30 %), each
rendered by the fast rasterizer and by the pbr path tracer (the same scenes: identical ground truth, depth and
masks, only rgb/ differs):

* fast only: A fast + B fast
* pbr only:  A pbr + B pbr
* mixture:   A fast + B pbr (70 % rasterized, 30 % path-traced: the recipe of the shipped checkpoint)

At 320x240 the shipped checkpoint is scored too, as a reference: it was trained by the README's recipe, which is
this mixture with 1000 images instead of 600 (70 + 30 scenes of the same seeds); ``--shipped-as-mixture`` lets it
stand for the mixture instead of training that one.

Each model is scored (``simtest eval --estimator segicp --no-vsd``, ADD(-S)-0.1d and AR = mean of AR_MSSD and
AR_MSPD) on held-out scenes (seed 2) rendered by the fast, quality and pbr profiles, and on the same scenes with
looks no training image had: ``materials.first_variant = 1000`` gives every material, environment and object print
a seed outside the training's range (fast and pbr). Training CPU minutes are the trainer process's user + system
time.

Each step is skipped when its output is complete (``generate --resume``, ``train --resume``, an evaluation with its
``metrics.json``), so an interrupted run continues where it stopped. The table is written to ``OUT/transfer.md``
and ``OUT/transfer.json`` and printed.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

#: Seeds of the datasets (train A, train B, validation, test).
SEEDS = {"A": 0, "B": 10, "val": 1, "test": 2}
#: The models: name -> (dataset of set A, dataset of set B).
MODELS = {"fast only": ("A_fast", "B_fast"), "pbr only": ("A_pbr", "B_pbr"), "mixture": ("A_fast", "B_pbr")}
#: The row of the shipped checkpoint (evaluated at the full size only: it is made for 320x240).
SHIPPED = "shipped checkpoint"
#: The test sets: column name -> (dataset name, profile, unseen looks).
TESTS = {"fast": ("test_fast", "fast", False), "quality": ("test_quality", "quality", False),
         "pbr": ("test_pbr", "pbr", False), "unseen looks, fast": ("test_unseen_fast", "fast", True),
         "unseen looks, pbr": ("test_unseen_pbr", "pbr", True)}
UNSEEN_CONFIG = "[materials]\nfirst_variant = 1000\n"


@dataclass(frozen=True)
class Size:
    scenes_a: int
    scenes_b: int
    views: int
    test_scenes: int
    test_views: int
    epochs: int
    width: int = 320
    height: int = 240


FULL = Size(scenes_a=42, scenes_b=18, views=10, test_scenes=10, test_views=6, epochs=36)
SMALL = Size(scenes_a=3, scenes_b=2, views=2, test_scenes=2, test_views=2, epochs=1, width=160, height=120)


def _simtest(args: list[str], log: Path) -> float:
    """Run ``simtest ARGS`` (stdout and stderr to ``log``); returns its CPU seconds (user + system)."""
    cmd = [sys.executable, "-m", "simtest", *args]
    with open(log, "a") as fh:
        fh.write("$ simtest " + " ".join(args) + "\n")
        fh.flush()
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, stdout=fh, stderr=subprocess.STDOUT)
        _, status, usage = os.wait4(proc.pid, 0)
        proc.returncode = os.waitstatus_to_exitcode(status)
        fh.write(f"# rc {proc.returncode}, {time.perf_counter() - t0:.0f} s wall, "
                 f"{usage.ru_utime + usage.ru_stime:.0f} s CPU\n")
    if proc.returncode != 0:
        raise SystemExit(f"simtest {' '.join(args[:2])} failed (rc {proc.returncode}); see {log}")
    return usage.ru_utime + usage.ru_stime


def _datasets(size: Size, out: Path) -> dict[str, list[str]]:
    """``{dataset name: simtest generate arguments}`` of every dataset the table needs."""
    common = ["--objects", "builtin-small", "--width", str(size.width), "--height", str(size.height),
              "--workers", "1", "--quiet", "--resume"]
    sets = {}
    for part, scenes in (("A", size.scenes_a), ("B", size.scenes_b)):
        for profile in ("fast", "pbr"):
            sets[f"{part}_{profile}"] = ["--scenes", str(scenes), "--frames-per-scene", str(size.views),
                                         "--seed", str(SEEDS[part]), "--profile", profile]
    sets["val"] = ["--scenes", str(max(1, size.test_scenes * 6 // 10)), "--frames-per-scene",
                   str(max(1, size.test_views * 5 // 6)), "--seed", str(SEEDS["val"])]
    for name, profile, unseen in TESTS.values():
        sets[name] = ["--scenes", str(size.test_scenes), "--frames-per-scene", str(size.test_views),
                      "--seed", str(SEEDS["test"]), "--profile", profile]
        if unseen:
            sets[name] += ["--config", str(out / "unseen.toml")]
    return {name: ["generate", *args, *common, "--out", str(out / "data" / name)] for name, args in sets.items()}


def _train_args(size: Size, out: Path, model: str) -> list[str]:
    a, b = MODELS[model]
    return ["train", "segmentation", "--data", str(out / "data" / a), "--data", str(out / "data" / b),
            "--val", str(out / "data" / "val"), "--out", str(_run_dir(out, model)), "--epochs", str(size.epochs),
            "--crop", f"{min(160, size.height)}x{min(160, size.width)}", "--depth-input", "--threads", "1",
            "--seed", "0", "--quiet", "--resume"]


def _run_dir(out: Path, model: str) -> Path:
    return out / "runs" / model.split(" ")[0]


def _eval_dir(out: Path, model: str, test: str) -> Path:
    return out / "eval" / model.split(" ")[0] / TESTS[test][0]


def _parallel(jobs: int, fns) -> list:
    with ThreadPoolExecutor(jobs) as pool:
        return [f.result() for f in [pool.submit(fn) for fn in fns]]


def _rows(size: Size, shipped_as_mixture: bool) -> list[str]:
    """The table's rows: the models to train (:data:`MODELS`) and, at 320x240, the shipped checkpoint."""
    rows = [m for m in MODELS if not (shipped_as_mixture and m == "mixture")]
    return rows + ([SHIPPED] if (size.width, size.height) == (320, 240) else [])


def run(out: Path, size: Size, jobs: int = 2, shipped_as_mixture: bool = False) -> dict:
    """Make the datasets, train the models, evaluate them and return the table's numbers."""
    out.mkdir(parents=True, exist_ok=True)
    (out / "unseen.toml").write_text(UNSEEN_CONFIG)
    log = out / "log"
    log.mkdir(exist_ok=True)
    datasets = _datasets(size, out)
    print(f"datasets: {', '.join(datasets)}", flush=True)
    _parallel(jobs, [lambda n=n, a=a: _simtest(a, log / f"generate_{n}.log") for n, a in datasets.items()])
    cpu_file = out / "train_cpu.json"
    cpu = json.loads(cpu_file.read_text()) if cpu_file.exists() else {}
    rows = _rows(size, shipped_as_mixture)
    todo = [m for m in rows if m in MODELS and not (_run_dir(out, m) / "model.pt").exists()]
    print(f"training: {', '.join(todo) or 'done'}", flush=True)
    spent = _parallel(jobs, [lambda m=m: _simtest(_train_args(size, out, m), log / f"train_{m.split(' ')[0]}.log")
                             for m in todo])
    for m, seconds in zip(todo, spent):
        cpu[m] = cpu.get(m, 0.0) + seconds
    cpu_file.write_text(json.dumps(cpu, indent=1))
    evals = [(m, t) for m in rows for t in TESTS if not (_eval_dir(out, m, t) / "metrics.json").exists()]
    print(f"evaluations: {len(evals)}", flush=True)

    def checkpoint(m: str) -> list[str]:
        return [] if m == SHIPPED else ["--opt", f"checkpoint={_run_dir(out, m) / 'model.pt'}"]

    _parallel(jobs, [lambda m=m, t=t: _simtest(
        ["eval", "--estimator", "segicp", *checkpoint(m), "--data", str(out / "data" / TESTS[t][0]),
         "--out", str(_eval_dir(out, m, t)), "--no-vsd", "--quiet", "--overwrite"],
        log / f"eval_{m.split(' ')[0]}_{TESTS[t][0]}.log") for m, t in evals])
    table = {"size": size.__dict__, "rows": rows, "train_cpu_min": {m: cpu[m] / 60.0 for m in rows if m in cpu},
             "cells": {}}
    for m in rows:
        for t in TESTS:
            metrics = json.loads((_eval_dir(out, m, t) / "metrics.json").read_text())
            table["cells"][f"{m} | {t}"] = _scores(metrics)
    return table


def _scores(metrics: dict) -> dict:
    """ADD(-S)-0.1d and AR (%) and the target count from an evaluation's ``metrics.json``."""
    agg = metrics["overall"]
    return {"add": 100.0 * float(agg["add_s_or_add_01d"]), "ar": 100.0 * float(agg["ar"]),
            "targets": int(agg["num_targets"])}


def markdown(table: dict) -> str:
    size = table["size"]
    lines = [f"segicp, builtin-small at {size['width']}x{size['height']}: "
             f"{(size['scenes_a'] + size['scenes_b']) * size['views']} training images per model "
             f"({size['scenes_a']} + {size['scenes_b']} scenes x {size['views']} views), {size['epochs']} epochs; "
             f"test: {size['test_scenes']} scenes x {size['test_views']} views (seed 2). "
             "Cells: ADD(-S)-0.1d / AR (MSSD, MSPD) [%].", "",
             "| trained on | " + " | ".join(TESTS) + " | fast -> pbr | train CPU min |",
             "|---|" + "---:|" * (len(TESTS) + 2)]
    for m in table["rows"]:
        cells = [table["cells"][f"{m} | {t}"] for t in TESTS]
        gap = table["cells"][f"{m} | pbr"]["add"] - table["cells"][f"{m} | fast"]["add"]
        minutes = table["train_cpu_min"].get(m)
        lines.append(f"| {m} | " + " | ".join(f"{c['add']:.1f} / {c['ar']:.1f}" for c in cells)
                     + f" | {gap:+.1f} | {'-' if minutes is None else f'{minutes:.1f}'} |")
    targets = sorted({c["targets"] for c in table["cells"].values()})
    lines += ["", f"targets per test set: {', '.join(map(str, targets))}"]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True, help="working folder (datasets, runs, evaluations, the table)")
    p.add_argument("--small", action="store_true", help="toy size: checks the steps in minutes")
    p.add_argument("--jobs", type=int, default=2, help="simtest processes at once (default 2)")
    p.add_argument("--shipped-as-mixture", action="store_true",
                   help="the shipped checkpoint stands for the mixture (its recipe) instead of training it again")
    args = p.parse_args(argv)
    out = Path(args.out)
    table = run(out, SMALL if args.small else FULL, args.jobs, args.shipped_as_mixture)
    text = markdown(table)
    (out / "transfer.json").write_text(json.dumps(table, indent=1))
    (out / "transfer.md").write_text(text + "\n")
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
