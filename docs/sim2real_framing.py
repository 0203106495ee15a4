"""Where the framing search starts: per detector region on its object, the template pose found from each start.

The template stage frames a detector region's crop by the region's box (margin 1.2) and the framing search
(:mod:`simtest.estimators.templates.framing`) moves and scales that window while the templates match it better.
On real LM-O frames the detectors' regions often hold only part of their object (a median 56 % of the can's and
39 % of the driller's visible mask), and a window framed on a part is too small for the search's steps to grow out
of. This script measures it: for every region of the shipped detectors (pooled, up to ``--candidates`` per
object) that covers more than 10 % of a target's visible mask, the framing search is run from the region's
window scaled by each of ``--starts``, and the matched template's pose (before the local search and the outline
fit) is scored against that target: ADD(-S) within 0.1 d, and "near" (rotation within 20 degrees over the
object's symmetries and translation within 5 cm). Then, for sets of starts, the pose of the best-matching start
(what ``--opt framing_starts=(...)`` keeps) and the best of them (an oracle). Needs visible masks
(``simtest masks``). Run from the repository root::

    simtest masks --data LMO --out LMO-masked
    python docs/sim2real_framing.py --data LMO-masked --max-images 25 --out runs/framing.jsonl
    python docs/sim2real_framing.py --data LMO-masked --score-only --out runs/framing.jsonl
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from simtest.evaluation.images import observation  # noqa: E402
from simtest.estimators.templates.estimator import TemplateEstimator  # noqa: E402
from simtest.estimators.templates.match import template_pose  # noqa: E402
from simtest.io import bop  # noqa: E402
from simtest.io.dataset import image_size, select_images  # noqa: E402
from simtest.metrics.pose import add, adi, re_sym  # noqa: E402
from simtest.objects.loaders import load_dataset_objects  # noqa: E402

#: A region counts when it covers more than this fraction of a target's visible mask.
MIN_COVER = 0.1


def _start(est: TemplateEstimator, rgb: np.ndarray, K: np.ndarray, mask: np.ndarray, obj, gt, syms) -> list[dict]:
    """The region's crop matched as the estimator does, then one framing search per start of ``est``."""
    bank, weights = est.bank(obj)
    crops, _, _, a, _, _ = est.region_match(weights, rgb, mask, K)
    metric = adi if obj.is_symmetric else add
    out = []
    for f, fr in zip(est.framing_starts, est.framings(rgb, K, crops[a], float(est.inplane[a]), weights)):
        R, t = template_pose(bank, fr.template, fr.crop.K, fr.crop.R_virt)
        out.append({"start": f, "score": fr.score, "re": re_sym(R, gt.T_cam_obj.R, syms),
                    "te": float(np.linalg.norm(t - gt.T_cam_obj.t)),
                    "err_d": metric(R, t, gt.T_cam_obj.R, gt.T_cam_obj.t, obj.vertices) / float(obj.diameter)})
    return out


def dump(data: Path, out: Path, factors: list[float], candidates: int, max_images: int | None) -> None:
    """One JSON line per image: per counted region its object, coverage and the pose of every start."""
    objects = load_dataset_objects(data)
    refs = select_images(data, None, None, max_images, objects.ids)
    width, height = image_size(data)
    est = TemplateEstimator(detect="rgb", candidates=candidates, framing=True, refine="none", framing_starts=factors)
    syms: dict[int, np.ndarray] = {}
    with open(out, "w") as f:
        for i, ref in enumerate(refs):
            t0 = time.perf_counter()
            obs, tg = observation(ref, objects, "gt-masks", width, height, False)
            rgb, K = np.asarray(obs.rgb), np.asarray(obs.K, np.float64)
            masks = {j: bop.read_mask(ref.gt_dir, ref.im_id, j, visible=True) for j, _ in tg}
            rows = []
            for _, oid, mask, _ in est.regions(obs):
                mine = [(j, g) for j, g in tg if g.obj_id == oid]
                cover = [float((masks[j] & mask).sum() / max(int(masks[j].sum()), 1)) for j, _ in mine]
                if not cover or max(cover) <= MIN_COVER:
                    continue
                obj = objects.get(oid)
                syms.setdefault(oid, obj.symmetry_transforms())
                g = mine[int(np.argmax(cover))][1]
                rows.append({"obj_id": oid, "cover": max(cover),
                             "starts": _start(est, rgb, K, mask, obj, g, syms[oid])})
            f.write(json.dumps({"scene_id": ref.scene_id, "im_id": ref.im_id, "regions": rows}) + "\n")
            f.flush()
            print(f"{i + 1}/{len(refs)} image {ref.im_id}: {len(rows)} regions, {time.perf_counter() - t0:.1f} s",
                  flush=True)


def score(out: Path) -> list[str]:
    """Lines of the summary: per start and per set of starts, the regions whose pose passes and is near."""
    regions = [r for line in open(out) for r in json.loads(line)["regions"]]
    factors = [s["start"] for s in regions[0]["starts"]] if regions else []

    def counts(picked: list[dict]) -> str:
        ok = sum(s["err_d"] < 0.1 for s in picked)
        near = sum(s["re"] < 20.0 and s["te"] < 0.05 for s in picked)
        return f"ADD(-S)-0.1d {ok:4d}, near {near:4d} of {len(picked)} regions"

    lines = []
    for k in range(1, len(factors) + 1):
        for subset in itertools.combinations(range(len(factors)), k):
            chosen = [max((r["starts"][i] for i in subset), key=lambda s: s["score"]) for r in regions]
            best = [min((r["starts"][i] for i in subset), key=lambda s: s["err_d"]) for r in regions]
            name = ",".join(f"{factors[i]:g}" for i in subset)
            lines.append(f"starts {name:14s} best match: {counts(chosen)}   oracle: {counts(best)}")
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--out", type=Path, required=True, help="JSON-lines file of the regions")
    ap.add_argument("--starts", default="0.7,1,1.4,2", help="window factors, comma-separated")
    ap.add_argument("--candidates", type=int, default=3)
    ap.add_argument("--max-images", type=int, default=None)
    ap.add_argument("--score-only", action="store_true")
    args = ap.parse_args(argv)
    if not args.score_only:
        dump(args.data, args.out, [float(v) for v in args.starts.split(",")], args.candidates, args.max_images)
    print("\n".join(score(args.out)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
