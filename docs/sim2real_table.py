"""The real transfer table of docs/sim2real.md from `simtest eval` run folders.

Each row is one trained variant: its evaluation on the real LM-O frames and, beside it, on a held-out simtest
set of the same objects (the sim-to-sim number), with the training CPU minutes. Run from the repository root::

    python docs/sim2real_table.py \\
        --row "eff+color+bg|RUNS/real-eval|RUNS/sim-eval|312" \\
        --row "..." --out docs/sim2real_table.md

A row is ``NAME|REAL_EVAL_DIR|SIM_EVAL_DIR|CPU_MINUTES`` (an empty field: not measured). ``--skip-images 25``
scores the real runs without their first 25 images (by scene and image id): the frames no choice was tuned on.
Every accuracy comes with its target count and a 95 % interval: Wilson for ADD(-S)-0.1d (a proportion of
targets), a normal interval of the per-target recalls for AR_MSSD and AR_MSPD (each target's recall is the fraction of the ten BOP
thresholds its error is within; their mean over the targets is the AR). The frames of one real sequence are
correlated, so the intervals are narrower than a second scene would show.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from simtest.metrics.intervals import wilson_interval  # noqa: E402
from simtest.metrics.bop19 import MSPD_THETAS, MSSD_THETAS  # noqa: E402

LMO_NAMES = {1: "ape", 5: "can", 6: "cat", 8: "driller", 9: "duck", 10: "eggbox", 11: "glue", 12: "holepuncher"}


def per_target(run: Path, skip_images: int = 0, first_images: int | None = None) -> list[dict[str, float]]:
    """Per target of a run folder's errors.csv: ADD(-S)-0.1d hit (0/1) and its MSSD and MSPD recalls; with
    ``skip_images`` the targets of the run's first images (by scene and image id) are left out, with
    ``first_images`` only those of its first images are kept."""
    out = []
    with open(run / "errors.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    images = sorted({(int(r["scene_id"]), int(r["im_id"])) for r in rows})
    kept = set(images[skip_images:] if first_images is None else images[:first_images])
    for row in rows:
        if (int(row["scene_id"]), int(row["im_id"])) in kept:
            matched = row["matched"] == "1"
            d = float(row["diameter_m"])
            adds = float(row["add_s_or_add"]) if matched and row["add_s_or_add"] else math.inf
            mssd = float(row["mssd"]) if matched and row["mssd"] else math.inf
            mspd = float(row["mspd"]) if matched and row["mspd"] else math.inf
            out.append({"obj_id": int(row["obj_id"]), "add": float(adds < 0.1 * d),
                        "mssd": sum(mssd < t * d for t in MSSD_THETAS) / len(MSSD_THETAS),
                        "mspd": sum(mspd < t for t in MSPD_THETAS) / len(MSPD_THETAS)})
    return out


def rate(values: list[float]) -> str:
    """``12.3 % [10.1, 14.8] (n=734)``: a proportion with its Wilson interval."""
    n, k = len(values), int(round(sum(values)))
    lo, hi = wilson_interval(k, n)
    return f"{100 * k / n:.1f} [{100 * lo:.1f}, {100 * hi:.1f}]"


def mean_ci(values: list[float]) -> str:
    """The mean of per-target recalls with a normal 95 % interval."""
    n = len(values)
    m = sum(values) / n
    sd = math.sqrt(sum((v - m) ** 2 for v in values) / max(n - 1, 1))
    h = 1.959963984540054 * sd / math.sqrt(n)
    return f"{m:.3f} [{max(0.0, m - h):.3f}, {min(1.0, m + h):.3f}]"


def check_against_metrics(run: Path, rows: list[dict[str, float]]) -> None:
    """The per-target recomputation must give the run's own overall numbers (same thresholds, same rule)."""
    overall = json.loads((run / "metrics.json").read_text())["overall"]
    for key, mine in (("add_s_or_add_01d", "add"), ("ar_mssd", "mssd"), ("ar_mspd", "mspd")):
        ours = sum(r[mine] for r in rows) / len(rows)
        if overall.get(key) is not None and abs(ours - overall[key]) > 1e-9:
            raise SystemExit(f"{run}: recomputed {key} {ours} differs from metrics.json's {overall[key]}")


def table(specs: list[str], skip_images: int = 0, first_images: int | None = None) -> str:
    ids = sorted(LMO_NAMES)
    head = ["variant", "real ADD(-S)-0.1d %", "real AR_MSSD", "real AR_MSPD"] + \
        [f"{LMO_NAMES[i]}" for i in ids] + ["sim ADD(-S)-0.1d %", "train CPU min"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    n_real = n_sim = None
    for spec in specs:
        name, real, sim, cpu = (spec.split("|") + ["", "", ""])[:4]
        cells = [name]
        rows = per_target(Path(real), skip_images, first_images)
        if not skip_images and first_images is None:
            check_against_metrics(Path(real), rows)
        n_real = len(rows)
        cells += [rate([r["add"] for r in rows]), mean_ci([r["mssd"] for r in rows]),
                  mean_ci([r["mspd"] for r in rows])]
        for i in ids:
            sel = [r["add"] for r in rows if r["obj_id"] == i]
            cells.append(f"{100 * sum(sel) / len(sel):.1f}" if sel else "-")
        if sim:
            srows = per_target(Path(sim))
            check_against_metrics(Path(sim), srows)
            n_sim = len(srows)
            cells.append(rate([r["add"] for r in srows]))
        else:
            cells.append("-")
        cells.append(cpu or "-")
        lines.append("| " + " | ".join(cells) + " |")
    frames = f"the first {first_images}" if first_images is not None else \
        f"the last {100 - skip_images}" if skip_images else "the 100"
    notes = f"\nReal: {n_real} targets of {frames} real LM-O frames." + \
        (f" Sim: {n_sim} targets of the held-out simtest set." if n_sim else "") + \
        " Per-object columns: real ADD(-S)-0.1d %. Brackets: 95 % intervals (see docs/sim2real_table.py).\n"
    return "\n".join(lines) + "\n" + notes


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--row", action="append", required=True, metavar="NAME|REAL|SIM|CPU_MIN")
    ap.add_argument("--skip-images", type=int, default=0, metavar="N",
                    help="leave out the real run's first N images (those a choice was tuned on)")
    ap.add_argument("--first-images", type=int, metavar="N",
                    help="keep only the real run's first N images (those choices are made on)")
    ap.add_argument("--out", type=Path, help="also write the table here")
    args = ap.parse_args()
    if args.first_images is not None and args.skip_images:
        ap.error("--first-images and --skip-images exclude each other")
    text = table(args.row, args.skip_images, args.first_images)
    print(text)
    if args.out:
        args.out.write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
