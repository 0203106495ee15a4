"""Candidate regions for the template estimator on a BOP dataset: every candidate's pose error, and the rate of
each rule that keeps one (docs/sim2real.md, "Third round").

The ``templates`` estimator with the shipped detector (``detect=rgb``) and ``candidates=K`` poses the top ``K``
regions of each object the image is known to hold (ranked by mean class probability). This script runs it over
the dataset's images and writes, per candidate, its region probability, template-match score, silhouette fit
and ADD(-S) error against the image's target of that object (ground truth used only to score, after the
estimate); then prints ADD(-S)-0.1d over all targets for each rule that picks one candidate per object
(``prob``: the first region, ``match``: the best template match, ``match_prob``: their product, ``oracle``:
the best candidate, what a perfect verifier reaches), each for the silhouette-fitted pose and for the matched
template's pose without the fit. With a dataset that has visible masks (``simtest masks``) each candidate also
gets its region's IoU with the target's mask. With ``--outline FILE`` every candidate is also fitted to that
outline network's mask, as LM-O's default fits its kept poses (``soft+flip`` at ``--temperature``), and the rules
are scored on the fitted poses too. ``top k`` keeps the candidates of rank below ``k`` (a second pooled
detector's regions come after the first's); ``all`` keeps every candidate. Run from the repository root::

    simtest masks --data LMO --out LMO-masked
    python docs/sim2real_candidates.py --data LMO-masked --candidates 3 --out runs/candidates.jsonl
    python docs/sim2real_candidates.py --data LMO-masked --score-only --out runs/candidates.jsonl
    W=simtest/estimators/weights
    python docs/sim2real_candidates.py --data LMO-masked --candidates 3 --max-images 25 --out runs/c.jsonl \
        --outline $W/templates_outline_lmo_640x480.onnx --opt framing=true --opt refine=none --opt local_deg=4 \
        --opt region_threshold=0.1 \
        --opt "detector=$W/keypoints_detector_lmo_640x480.onnx+$W/keypoints_detector_lmo_640x480.clutter.onnx"
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from simtest.metrics.intervals import wilson_interval  # noqa: E402
from simtest.evaluation.images import observation  # noqa: E402
from simtest.estimators.templates.estimator import TemplateEstimator  # noqa: E402
from simtest.estimators.keypoints.crop_infer import TEMPLATE_OUTLINE_MASK, TEMPLATE_OUTLINE_TEMPERATURE  # noqa: E402
from simtest.estimators.templates.outline import OutlineNet, outline_fit  # noqa: E402
from simtest.io import bop  # noqa: E402
from simtest.io.dataset import image_size, select_images  # noqa: E402
from simtest.metrics.pose import add, adi  # noqa: E402
from simtest.objects.loaders import load_dataset_objects  # noqa: E402

RULES = ("prob", "match", "match_prob", "oracle")


def dump(data: Path, out: Path, candidates: int, max_images: int | None, opts: dict, outline: Path | None = None,
         temperature: float = TEMPLATE_OUTLINE_TEMPERATURE) -> None:
    """Write one JSON line per image: its targets and every candidate with its ADD(-S) error (metres), and with
    ``outline`` the error after the outline fit (``error_outlined``)."""
    objects = load_dataset_objects(data)
    refs = select_images(data, None, None, max_images, objects.ids)
    width, height = image_size(data)
    est = TemplateEstimator(detect="rgb", candidates=candidates, **opts)
    net = None if outline is None else OutlineNet(outline)
    with open(out, "w") as f:
        for i, ref in enumerate(refs):
            t0 = time.perf_counter()
            obs, tg = observation(ref, objects, "gt-masks", width, height, False)
            est.estimate(obs)
            targets = [{"gt_id": j, "obj_id": int(g.obj_id), "diameter": float(objects.get(g.obj_id).diameter)}
                       for j, g in tg]
            cands = []
            for c in est.last_candidates:
                obj = objects.get(c["obj_id"])
                mine = [(j, g) for j, g in tg if g.obj_id == c["obj_id"]]
                metric = adi if obj.is_symmetric else add
                errs = [metric(c["R"], c["t"], g.T_cam_obj.R, g.T_cam_obj.t, obj.vertices) for _, g in mine]
                if net is not None:
                    fit = outline_fit(net, obj, np.asarray(obs.rgb), obs.K, c["R"], c["t"],
                                      mask_mode=TEMPLATE_OUTLINE_MASK, temperature=temperature)
                    fitted = [metric(fit.R, fit.t, g.T_cam_obj.R, g.T_cam_obj.t, obj.vertices) for _, g in mine]
                t0m = np.asarray(c["info"].get("t_matched", c["t"]))
                sil = c["info"].get("silhouette") or c["info"].get("edges") or {}
                cands.append({"obj_id": c["obj_id"], "rank": c["rank"], "prob": c["prob"], "match": c["match"],
                              "pixels": c["pixels"], "iou_before": sil.get("iou_before"),
                              "iou_after": sil.get("iou_after"), "scale": sil.get("scale"),
                              "error": min(errs) if errs else None,
                              "error_matched": min(metric(c["R"], t0m, g.T_cam_obj.R, g.T_cam_obj.t, obj.vertices)
                                                   for _, g in mine) if mine else None,
                              "te": min(float(np.linalg.norm(c["t"] - g.T_cam_obj.t)) for _, g in mine)
                              if mine else None,
                              "region_iou": _region_iou(ref, c["mask"], mine),
                              **({} if net is None else {"error_outlined": min(fitted) if fitted else None})})
            f.write(json.dumps({"scene_id": ref.scene_id, "im_id": ref.im_id, "targets": targets,
                                "candidates": cands}) + "\n")
            f.flush()
            print(f"{i + 1}/{len(refs)} image {ref.im_id}: {len(cands)} candidates, "
                  f"{time.perf_counter() - t0:.1f} s", flush=True)


def _region_iou(ref, mask: np.ndarray, mine: list) -> float | None:
    """The best IoU of a candidate region with the visible masks of the image's targets of its object (None
    where the dataset has no masks)."""
    if not ref.has_masks or not mine:
        return None
    best = 0.0
    for j, _ in mine:
        m = bop.read_mask(ref.gt_dir, ref.im_id, j, visible=True)
        best = max(best, float((m & mask).sum() / max((m | mask).sum(), 1)))
    return best


def pick(cands: list[dict], rule: str) -> dict | None:
    """The candidate ``rule`` keeps among one object's candidates."""
    if not cands:
        return None
    key = {"prob": lambda c: -c["rank"], "match": lambda c: c["match"],
           "match_prob": lambda c: c["match"] * c["prob"],
           "oracle": lambda c: -(c["error"] if c["error"] is not None else math.inf)}[rule]
    return max(cands, key=key)


def score(out: Path, max_rank: int | None = None, key: str = "error") -> dict[str, tuple[int, int]]:
    """``{rule: (hits, targets)}`` of ADD(-S)-0.1d over the dumped images (candidates of rank < ``max_rank``),
    of the silhouette-fitted poses (``key="error"``) or of the matched template's pose (``"error_matched"``)."""
    res = {r: [0, 0] for r in RULES}
    for line in open(out):
        im = json.loads(line)
        for t in im["targets"]:
            cands = [dict(c, error=c[key]) for c in im["candidates"] if c["obj_id"] == t["obj_id"]
                     and (max_rank is None or c["rank"] < max_rank)]
            for r in RULES:
                c = pick(cands, r)
                res[r][1] += 1
                res[r][0] += c is not None and c["error"] is not None and c["error"] < 0.1 * t["diameter"]
    return {r: (h, n) for r, (h, n) in res.items()}


def _value(text: str) -> float | str:
    """An option's value: a number where it reads as one, else the text."""
    try:
        return float(text)
    except ValueError:
        return text


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--out", type=Path, required=True, help="JSON-lines file of the candidates")
    ap.add_argument("--candidates", type=int, default=3)
    ap.add_argument("--max-images", type=int, default=None)
    ap.add_argument("--opt", action="append", default=[], help="more estimator options KEY=VALUE")
    ap.add_argument("--score-only", action="store_true")
    ap.add_argument("--outline", type=Path, default=None, help="an outline network to fit every candidate to")
    ap.add_argument("--temperature", type=float, default=TEMPLATE_OUTLINE_TEMPERATURE,
                    help="the outline fit's temperature (default: LM-O's shipped one)")
    args = ap.parse_args(argv)
    if not args.score_only:
        opts = {k: _value(v) for k, v in (o.split("=", 1) for o in args.opt)}
        dump(args.data, args.out, args.candidates, args.max_images, opts, args.outline, args.temperature)
    keys = [("error", "silhouette-fitted"), ("error_matched", "matched template, no fit")]
    with open(args.out) as f:
        outlined = "error_outlined" in f.readline()
    if outlined:
        keys.append(("error_outlined", "outline-fitted"))
    for key, what in keys:
        for k in [*range(1, args.candidates + 1), None]:
            for rule, (h, n) in score(args.out, k, key).items():
                lo, hi = wilson_interval(h, n)
                top = "all" if k is None else f"top {k}"
                print(f"{what}: {top} {rule:10s} {100 * h / n:5.1f} % [{100 * lo:.1f}, {100 * hi:.1f}] of {n}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
