"""The template estimator (``templates``): pose from rendered templates and frozen ImageNet features. RGB only.

No training. Per object of the dataset a template bank is rendered from its model over the viewing sphere and
encoded once (:mod:`.bank`, cached). Per region to pose (a ground-truth visible mask with ``detect=gt``, else a
region of the shipped RGB detector of the ``keypoints`` estimator):

1. The region is cropped through a virtual camera aimed at its box (:mod:`.crops`), at ``inplane`` roll angles.
2. Each crop is encoded by the frozen EfficientNet-Lite0 (:mod:`.encoder`) and scored against every template
   (:mod:`.match`); the best (angle, template) gives the rotation, and the crop pixel and size of the template's
   object give the translation.
3. With ``framing`` the crop window is moved and scaled while the templates match it better (:mod:`.framing`):
   the translation then comes from the best-matching window, not from the region's outline. The search starts
   from the region's window scaled by each of ``framing_starts`` and the best-matching result is kept: a
   detector region that holds only part of its object (the real LM-O frames' can and driller) frames a window
   too small for the search's steps to grow out of.
4. With ``local_deg`` templates rendered on the fly around the best match replace it while they match better
   (:mod:`.local`).
5. With ``polish`` the framing is searched once more, in finer steps, against the final template alone; the
   matched pose's translation is then multiplied by ``depth_scale`` (1: unchanged; a calibration of the depth
   the match implies). Both are off by default: on the real LM-O frames neither raised ADD(-S)-0.1d
   (docs/sim2real.md, seventh round).
6. With ``refine="silhouette"`` the pose is fitted to the region's mask in the crop
   (:func:`simtest.estimators.silhouette.fit_translation`: depth, image position and small rotations); with
   ``refine="edges"`` the matched pose's outline is moved onto the image's edges (:mod:`.edges`: depth and
   image position), so the depth follows the real outline, not the region's.
7. With ``candidates`` > 1 (``detect=rgb``, target ids known) the detector's first ``candidates`` regions per
   expected instance are all posed, and per object the best (``select``: template match by default) are kept;
   every candidate of the last image is in :attr:`TemplateEstimator.last_candidates`.
8. With ``outline`` (an outline network, ``simtest train outlines``) every kept pose is fitted to the visible
   mask that network draws from the crop with the pose's silhouette as its prior (:mod:`.outline`: depth,
   image position and small turns from ``outline_deg``, the depth by at most ``outline_max_scale``).

On the 100 real LM-O frames (734 targets; docs/sim2real_templates.py) with ground-truth visible masks
(``detect=gt``, a diagnostic) and the defaults: 50.5 % [46.9, 54.1] ADD(-S)-0.1d, median rotation error
9.6 degrees, against 4.0 % [2.8, 5.6] and 107 degrees for the ``keypoints`` crop network on the same masks;
``local_deg=4`` raised it from 49.3 to 55.1 % on the first 40 frames (296 targets; twice the time per region).
With the shipped detector's regions (``detect=rgb``): 1.6 % [0.9, 2.8], median rotation error 72 degrees
(``keypoints``: 0.5 % [0.2, 1.4]); the detector's region holds the object for under half of the targets.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import replace
from typing import Any

import cv2
import numpy as np

from simtest.errors import ConfigError
from simtest.estimators.base import Observation, PoseEstimate
from simtest.estimators.templates.bank import RENDER_SIZE, BankSettings, TemplateBank, load_or_build, render_intrinsics
from simtest.estimators.templates.crops import mask_in_crop, region_crop, window_centre
from simtest.estimators.templates.edges import edge_distance, fit_edges
from simtest.estimators.templates.encoder import FeatureEncoder
from simtest.estimators.templates.export import default_encoder
from simtest.estimators.templates.framing import Framing, framing_search, hidden_cells
from simtest.estimators.templates.local import local_search
from simtest.estimators.templates.match import match_scores, template_coverage, template_pose, template_weights
from simtest.estimators.templates.outline import check_mask_mode, check_temperature, load_outline, outline_fit
from simtest.estimators.templates.render import ObjectRenderer

__all__ = ["TemplateEstimator", "DETECTORS", "REFINES", "SELECTS", "check_framing_starts", "pooled_regions"]

DETECTORS = ("rgb", "gt")
REFINES = ("none", "silhouette", "edges")
#: How one of an object's candidate regions is kept (``candidates`` > 1): the best template match
#: (``match``), the detector's region rank (``prob``: the first region, as with one candidate), or the match
#: times the detector's mean class probability (``match_prob``).
SELECTS = ("match", "prob", "match_prob")
#: Two candidate regions of one object overlapping more than this (IoU) are one region (posed once).
SAME_REGION_IOU = 0.8
#: A ``region_extra`` region overlapping an earlier region of its object more than this (IoU) is dropped.
EXTRA_REGION_IOU = 0.5


def check_framing_starts(starts, who: str = "templates: framing_starts") -> tuple[float, ...]:
    """``starts`` as a tuple of window factors, each a finite number in [0.25, 4]; a single number is one start.
    ``who`` names the option in the error.

    Raises:
        ConfigError: An empty list or a factor out of range, named with the value.
    """
    vals = (starts,) if isinstance(starts, (int, float)) else starts
    numbers = isinstance(vals, (list, tuple)) and all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                                      for v in vals)
    if not numbers or not vals or not all(0.25 <= float(v) <= 4.0 for v in vals):
        raise ConfigError(f"{who} must be window factors in [0.25, 4], e.g. (1, 1.4, 2), got {starts!r}")
    return tuple(float(v) for v in vals)


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max(int((a | b).sum()), 1))


def pooled_regions(segmenters: list, probs: list[np.ndarray], obs: Observation, per: int, rank: str,
                   threshold: float = 0.0, extra: float = 0.0) -> list[tuple[int, np.ndarray, float]]:
    """``(obj_id, mask (H, W) bool, mean class probability)`` of every candidate region of several detectors:
    each one's regions of ``obs`` (``probs``: its class probabilities; ``per``, ``rank``, ``threshold`` as in
    :meth:`~simtest.estimators.segicp.infer.Segmenter.regions`) in turn, a region overlapping an earlier one of
    its object at IoU > :data:`SAME_REGION_IOU` dropped; then with ``extra`` > 0 the same from the pixels whose
    class probability exceeds ``extra``, those overlapping an earlier one at IoU > :data:`EXTRA_REGION_IOU`
    dropped."""
    out: list[tuple[int, np.ndarray, float]] = []
    passes = [(threshold, SAME_REGION_IOU)] + ([(extra, EXTRA_REGION_IOU)] if extra > 0 else [])
    for level, same in passes:
        for segmenter, prob in zip(segmenters, probs):
            for o, m, p in segmenter.regions_in(prob, obs, per, rank, level):
                m = np.asarray(m, bool)
                if not any(r[0] == int(o) and _iou(r[1], m) > same for r in out):
                    out.append((int(o), m, float(p)))
    return out


def _union(masks: list[np.ndarray], shape: tuple[int, int]) -> np.ndarray:
    """(H, W) bool: the pixels of any of ``masks`` (each (H, W))."""
    out = np.zeros(shape, bool)
    for m in masks:
        out |= np.asarray(m, bool)
    return out


def _surplus(regions: list[tuple[int | None, int, np.ndarray, float]], target_obj_ids) -> bool:
    """Whether some object has more ``regions`` than it has expected instances (pooled detectors and extra
    regions can give one object several even with ``candidates=1``: they are then candidates too)."""
    wanted, found = Counter(int(o) for o in target_obj_ids), Counter(int(r[1]) for r in regions)
    return any(n > wanted[o] for o, n in found.items())


class TemplateEstimator:
    """Template matching pose estimator; see the module doc.

    Args:
        detect: ``rgb`` (the shipped RGB detector for the dataset's objects, or ``detector``) or ``gt``
            (ground-truth visible masks; runs are labelled ``(GT masks)``).
        detector: A segmentation checkpoint for ``detect=rgb`` (None: every shipped one that knows the objects,
            pooled); several joined by ``+`` pool their candidate regions (each gives ``candidates`` per object; a region
            that overlaps an earlier one of the same object at IoU > :data:`SAME_REGION_IOU` is posed once).
        views, min_elevation_deg, size, margin, stride, background: The bank's settings (:class:`BankSettings`).
        inplane_deg, inplane_range_deg: Roll angles tried per region: from ``-range`` to ``+range`` in steps of
            ``inplane_deg`` (degrees).
        query_mask: Weight the query's cells by its region mask too (:func:`match_scores`).
        refine: ``silhouette``, ``edges`` or ``none``; refine_deg: its first rotation step (degrees, 0:
            translation only);
            refine_max_scale: its largest relative depth change; refine_min_px: its smallest step (crop pixels).
        framing: Move and scale the crop window until the templates match it best (:mod:`.framing`), so
            the pose's depth and position no longer follow the region's outline.
        local_deg: First step (degrees) of the local template search around the best bank match (0: none;
            :mod:`.local`); local_min_deg: its last step (degrees; the step halves from ``local_deg`` down to it).
        candidates: With ``detect=rgb`` and known targets, the detector regions posed per expected instance
            (ranked by ``region_rank``); ``select`` decides which pose is kept (:data:`SELECTS`). With 1, an
            object that still gets more regions than instances (pooled detectors, ``region_extra``) has them all
            posed and as many kept, so it never gets more estimates than instances.
        region_threshold: With ``detect=rgb``, 0 takes regions from the detector's class map, above 0 from the
            pixels where the class's probability exceeds it (:meth:`~simtest.estimators.segicp.infer.
            Segmenter.regions`).
        region_extra: With ``detect=rgb`` and above 0: besides the regions ``region_threshold`` takes, each
            detector's regions of the pixels whose class probability exceeds it (as many per object), those
            overlapping none of the object's regions found so far at IoU > :data:`EXTRA_REGION_IOU`: an object
            whose pixels another class or the background narrowly wins still gets a candidate (0: none).
        polish: First aim step (a fraction of the window) of a last framing search against the final template
            alone (after the local search; 0: none), its size and roll steps in proportion (:mod:`.framing`),
            down to ``polish_min_shift``: finer than the first search, whose 600 templates make the score
            step-wise. The polished match (one template's score) is then what ``select=match`` compares.
        depth_scale: The matched pose's translation is multiplied by it (moved along its viewing ray, so the
            object stays on the same pixels): a calibration of the depth the template match implies. With the
            exact rotation that depth lies a median 1.7 % too far on real LM-O frames and 0.4 % on renders
            (docs/sim2real_depth.py); yet scaling every estimate did not raise the real score (seventh round).
        framing_starts: Factors of the region's window side (each in [0.25, 4]) from which the framing search
            starts; the best-matching framing is kept (ties: the first).
        occluders: Leave the pixels of the image's other regions out of the framing and local searches' scores
            (:mod:`.framing`; with ``candidates`` > 1 or a surplus of regions: the other objects' first regions),
            so that a partly hidden object is matched on its part in view.
        outline: An outline network (``.onnx`` or ``.pt`` of ``simtest train outlines``; several joined by ``+``
            are read as one, their probabilities averaged; None or False: none) that fits
            every kept pose to the object's visible mask (step 8); outline_max_scale: the largest relative depth
            change of that fit; outline_deg: its first rotation step in degrees (0: the rotation stays; 2 chosen
            on held-out renders, docs/sim2real.md, eighth round); outline_mask: how the fit reads the network's
            output (:data:`~simtest.estimators.templates.outline.MASK_MODES`: ``hard``, ``soft`` or
            ``soft+flip``; docs/sim2real.md, tenth round); outline_temperature: the logits' divisor before the
            sigmoid in the soft modes (> 1: flatter; LM-O's shipped choice 2, eleventh round).
        threads: CPU threads of the encoder. encoder: an ONNX file of the encoder (None: the shipped
            ``weights/templates_encoder_lite0.onnx``, or torch where it is missing).
    """

    #: Seconds one image may take (the evaluation's default limit is raised to it): the framing and local
    #: searches over every candidate region take 1-4 minutes per real LM-O frame on two busy cores.
    time_limit_s: float = 900.0

    def __init__(self, detect: str = "rgb", detector: str | None = None, views: int = 600,
                 min_elevation_deg: float = -20.0, size: int = 128, margin: float = 1.2, stride: int = 8,
                 inplane_deg: float = 10.0, inplane_range_deg: float = 60.0, query_mask: bool = True,
                 refine: str | None = "silhouette", refine_deg: float = 0.0, refine_max_scale: float = 0.3, refine_min_px: float = 0.5,
                 threads: int = 1, encoder: str | None = None, region_rank: str = "prob",
                 local_deg: float = 0.0, local_min_deg: float = 1.0, candidates: int = 1, select: str = "match", framing: bool = False,
                 region_threshold: float = 0.0, region_extra: float = 0.0, polish: float = 0.0, polish_min_shift: float = 0.0025,
                 depth_scale: float = 1.0, background: int = 0, outline: str | bool | None = None,
                 outline_max_scale: float = 0.1, outline_deg: float = 2.0, outline_mask: str = "hard",
                 outline_temperature: float = 1.0, framing_starts: tuple[float, ...] = (1.0,),
                 occluders: bool = False) -> None:
        if detect not in DETECTORS:
            raise ConfigError(f"templates: unknown detect {detect!r}; valid: {', '.join(DETECTORS)}")
        refine = "none" if refine is None else refine
        if refine not in REFINES:
            raise ConfigError(f"templates: unknown refine {refine!r}; valid: {', '.join(REFINES)}")
        if select not in SELECTS:
            raise ConfigError(f"templates: unknown select {select!r}; valid: {', '.join(SELECTS)}")
        if int(candidates) < 1:
            raise ConfigError(f"templates: need candidates >= 1, got {candidates!r}")
        if not float(local_min_deg) > 0 or (float(local_deg) > 0 and float(local_min_deg) > float(local_deg)):
            raise ConfigError(f"templates: need 0 < local_min_deg <= local_deg (degrees; a larger last step would "
                              f"skip the local search), got local_min_deg={local_min_deg!r}, local_deg={local_deg!r}")
        if not float(inplane_deg) > 0 or not float(inplane_range_deg) >= 0:
            raise ConfigError(f"templates: need inplane_deg > 0 and inplane_range_deg >= 0, got {inplane_deg!r}, "
                              f"{inplane_range_deg!r}")
        self.settings = BankSettings(views=int(views), min_elevation_deg=float(min_elevation_deg), size=int(size),
                                     margin=float(margin), stride=int(stride), background=int(background))
        self.settings.check()
        n = int(np.floor(float(inplane_range_deg) / float(inplane_deg) + 1e-9))
        self.inplane = np.radians(np.arange(-n, n + 1) * float(inplane_deg))
        self.detect, self.detector_path, self.region_rank = detect, detector, region_rank
        self.query_mask, self.refine = bool(query_mask), refine
        self.refine_deg, self.refine_max_scale = float(refine_deg), float(refine_max_scale)
        self.refine_min_px = float(refine_min_px)
        if encoder is None and default_encoder().is_file():
            encoder = str(default_encoder())
        self.encoder = FeatureEncoder(self.settings.stride, encoder, threads)
        self.needs_gt_masks = detect == "gt"
        self.needs_depth = False
        self.banks: dict[int, tuple[TemplateBank, np.ndarray]] = {}
        #: First step of the local template search (degrees; 0: none), :mod:`.local`.
        self.local_deg = float(local_deg)
        #: Last step of the local template search (degrees).
        self.local_min_deg = float(local_min_deg)
        self.renderers: dict[int, ObjectRenderer] = {}
        self.segmenter = None
        self.more_segmenters: list = []
        self.last_failures: list[dict[str, Any]] = []
        #: Search the crop window's position and size for the best template match (:mod:`.framing`).
        self.framing = bool(framing)
        #: Factors of the region's window side the framing search starts from.
        self.framing_starts = check_framing_starts(framing_starts)
        #: Other objects' regions are left out of the framing and local searches' scores.
        self.occluders = bool(occluders)
        #: Candidate regions posed per expected instance, and the rule that keeps one (:data:`SELECTS`).
        self.candidates, self.select = int(candidates), select
        if not 0.0 <= float(region_threshold) < 1.0:
            raise ConfigError(f"templates: region_threshold must be a class probability in [0, 1), got "
                              f"{region_threshold!r}")
        #: 0: regions from the class map; above 0: from the class probability above it.
        self.region_threshold = float(region_threshold)
        if not 0.0 <= float(region_extra) < 1.0:
            raise ConfigError(f"templates: region_extra must be a class probability in [0, 1), got {region_extra!r}")
        self.region_extra = float(region_extra)
        #: Every candidate of the last :meth:`estimate` (obj_id, rank, region probability, match, pose, kept).
        self.last_candidates: list[dict[str, Any]] = []
        if not 0.0 <= float(polish) < 0.5 or not 0.0 < float(polish_min_shift) < 0.5:
            raise ConfigError(f"templates: need polish and polish_min_shift in [0, 0.5) (fractions of the window; "
                              f"polish_min_shift above 0), got {polish!r}, {polish_min_shift!r}")
        if not 0.5 <= float(depth_scale) <= 2.0:
            raise ConfigError(f"templates: depth_scale must lie in [0.5, 2], got {depth_scale!r}")
        #: Factor of the matched pose's translation (its depth along the viewing ray).
        self.depth_scale = float(depth_scale)
        #: The last framing search against the final template (first aim step; 0: none), and its last step.
        self.polish, self.polish_min_shift = float(polish), float(polish_min_shift)
        #: The distance transform of the current image's edges (``refine="edges"``), made at first use.
        self._edges: np.ndarray | None = None
        if not 0.0 < float(outline_max_scale) < 1.0 or not 0.0 <= float(outline_deg) <= 10.0:
            raise ConfigError(f"templates: need outline_max_scale in (0, 1) and outline_deg in [0, 10] degrees, got "
                              f"{outline_max_scale!r}, {outline_deg!r}")
        check_mask_mode(outline_mask, "templates: outline_mask")
        check_temperature(outline_temperature, "templates: outline_temperature")
        #: The outline network of step 8 (None: no outline fit), and the largest depth change it may make.
        self.outline = None if outline in (None, False, "", "none") else load_outline(str(outline), threads=threads)
        self.outline_max_scale, self.outline_deg = float(outline_max_scale), float(outline_deg)
        self.outline_mask, self.outline_temperature = str(outline_mask), float(outline_temperature)

    def __repr__(self) -> str:
        return f"TemplateEstimator(detect={self.detect!r}, settings={self.settings!r}, refine={self.refine!r})"

    def bank(self, obj) -> tuple[TemplateBank, np.ndarray]:
        """``obj``'s bank and its template weights (built or read from the cache at first use)."""
        key = int(obj.obj_id) if hasattr(obj, "obj_id") else id(obj)
        if key not in self.banks:
            bank = load_or_build(obj, self.settings, self.encoder)
            self.banks[key] = (bank, template_weights(bank))
        return self.banks[key]

    def prepare(self, objects) -> None:
        """Once before the first image, outside its time limit, with ``detect="rgb"``: the detectors loaded and
        the bank of every object of ``objects`` they look for read from the cache or built (about a minute per
        object on two cores when the cache is cold). With ``detect="gt"`` the targets are not known before the
        images, so banks stay built at first use."""
        if self.detect != "rgb":
            return
        if self.segmenter is None:
            self._load_detector(objects)
        known = {i for s in [self.segmenter, *self.more_segmenters] for i in s.class_ids}
        for oid in [int(i) for i in objects.ids if int(i) in known]:
            self.bank(objects.get(oid))

    def regions(self, obs: Observation) -> list[tuple[int | None, int, np.ndarray, float]]:
        """``(target index or None, obj_id, mask (H, W) bool, detection score)`` per region to pose."""
        if self.detect == "gt":
            obs.require_targets("templates (detect=gt)")
            return [(k, int(o), np.asarray(m, bool), 1.0) for k, (o, m) in enumerate(zip(obs.target_obj_ids, obs.masks))
                    if np.asarray(m, bool).any()]
        if self.segmenter is None:
            self._load_detector(obs.objects)
        seen = replace(obs, depth=np.zeros(obs.rgb.shape[:2], np.float32))
        per = self.candidates if obs.target_obj_ids is not None else 1
        segmenters = [self.segmenter, *self.more_segmenters]
        probs = [s.probabilities(seen.rgb, seen.depth, np.asarray(seen.K, np.float64)) for s in segmenters]
        return [(None, o, m, p) for o, m, p in pooled_regions(segmenters, probs, seen, per, self.region_rank,
                                                              self.region_threshold, self.region_extra)]

    def _load_detector(self, objects) -> None:
        from simtest.estimators.segicp.infer import FORMAT as SEG_FORMAT, Segmenter
        from simtest.estimators.shipped import choose_all

        paths = str(self.detector_path).split("+") if self.detector_path is not None else [
            n.path for n in choose_all("keypoints_detector", SEG_FORMAT, objects, what="templates (its detector)",
                                       subset=True)]
        segmenters = [Segmenter(p, "cpu", 40, 1, runtime="auto") for p in paths]
        for segmenter in segmenters:
            segmenter.check_objects(objects)
        self.segmenter, self.more_segmenters = segmenters[0], segmenters[1:]

    def estimate(self, observation: Observation) -> list[PoseEstimate]:
        """Pose estimates (metres, camera frame) of the regions found (see the module doc). numpy's BLAS runs on
        at most ``threads`` threads meanwhile (:func:`simtest.backend.threads.blas_threads`), as the encoder does."""
        from simtest.backend.threads import blas_threads

        with blas_threads(self.encoder.threads):
            return self._estimate(observation)

    def _estimate(self, obs: Observation) -> list[PoseEstimate]:
        self.last_failures, self.last_candidates, self._edges = [], [], None
        K = np.asarray(obs.K, np.float64)
        regions = self.regions(obs)
        if self.detect == "rgb" and obs.target_obj_ids is not None and (
                self.candidates > 1 or _surplus(regions, obs.target_obj_ids)):
            return self._outlined(obs, self._estimate_candidates(obs, regions, K), K)
        out = []
        for n, (k, oid, mask, dscore) in enumerate(regions):
            obj = obs.objects.get(oid)
            others = [r[2] for j, r in enumerate(regions) if j != n]
            R, t, score, info = self._pose(obj, np.asarray(obs.rgb), mask, K, others)
            out.append(PoseEstimate(obj_id=oid, R=R, t=t, score=float(score * dscore), target_index=k, info=info))
        return self._outlined(obs, out, K)

    def _outlined(self, obs: Observation, found: list[PoseEstimate], K: np.ndarray) -> list[PoseEstimate]:
        """``found`` with every pose fitted to the outline network's mask (step 8; unchanged without one)."""
        if self.outline is None:
            return found
        rgb, out = np.asarray(obs.rgb), []
        for e in found:
            fit = outline_fit(self.outline, obs.objects.get(e.obj_id), rgb, K, e.R, e.t, self.outline_max_scale,
                              self.outline_deg, self.outline_mask, self.outline_temperature)
            out.append(replace(e, R=fit.R, t=fit.t, info={**e.info, "outline": fit.info()}))
        return out

    def _estimate_candidates(self, obs: Observation, regions: list[tuple[int | None, int, np.ndarray, float]],
                             K: np.ndarray) -> list[PoseEstimate]:
        """Per object, every candidate region posed and as many kept as instances are expected (``select``).
        A candidate's pixels are not counted against another object's first region, nor the reverse."""
        wanted = [int(o) for o in obs.target_obj_ids]
        by_obj: dict[int, list[tuple[np.ndarray, float]]] = {}
        for _, oid, mask, dscore in regions:
            by_obj.setdefault(oid, []).append((mask, dscore))
        out = []
        for oid, cands in by_obj.items():
            obj = obs.objects.get(oid)
            others = [c[0][0] for o, c in by_obj.items() if o != oid]
            posed = []
            for rank, (mask, dscore) in enumerate(cands):
                R, t, score, info = self._pose(obj, np.asarray(obs.rgb), mask, K, others)
                key = {"match": score, "prob": -rank, "match_prob": score * dscore}[self.select]
                posed.append((key, rank, R, t, score, dscore, info))
                self.last_candidates.append({"obj_id": oid, "rank": rank, "prob": dscore, "match": float(score),
                                             "pixels": int(mask.sum()), "mask": mask, "R": R, "t": t,
                                             "info": info, "kept": False})
            posed.sort(key=lambda p: (-p[0], p[1]))
            first = len(self.last_candidates) - len(cands)
            for key, rank, R, t, score, dscore, info in posed[:wanted.count(oid)]:
                self.last_candidates[first + rank]["kept"] = True
                out.append(PoseEstimate(obj_id=oid, R=R, t=t, score=float(score * dscore), target_index=None,
                                        info={**info, "candidate": rank, "candidates": len(cands)}))
        return out

    def region_match(self, weights: np.ndarray, rgb: np.ndarray, mask: np.ndarray, K: np.ndarray
                     ) -> tuple[list, np.ndarray, np.ndarray | None, int, int, float]:
        """Step 1-2 for one region ``mask`` (H, W) bool: its crops at every roll, their unit features (n, C, h, w)
        and cell masks (or None without ``query_mask``), and the best (roll index, template index, score)
        against the templates ``weights``."""
        crops = [region_crop(rgb, mask, K, self.settings.size, self.settings.margin, a) for a in self.inplane]
        q = self.encoder.features(np.stack([c.rgb for c in crops]))
        qm = None
        if self.query_mask:
            h, w = q.shape[-2:]
            qm = np.stack([cv2.resize(c.mask.astype(np.float32), (w, h), interpolation=cv2.INTER_AREA) for c in crops])
        scores = match_scores(q, weights, qm)
        a, j = np.unravel_index(int(np.argmax(scores)), scores.shape)
        return crops, q, qm, int(a), int(j), float(scores[a, j])

    def framings(self, rgb: np.ndarray, K: np.ndarray, crop, roll_rad: float, weights: np.ndarray,
                 hidden: np.ndarray | None = None, coverage: np.ndarray | None = None) -> list[Framing]:
        """Step 3: one framing search per factor of :attr:`framing_starts`, each from ``crop``'s window (centre
        kept, side scaled by the factor) at the roll ``roll_rad`` (radians), against the templates ``weights``
        (``hidden`` pixels left out, with the templates' ``coverage``)."""
        centre, side = window_centre(crop, K), crop.window[2]
        return [framing_search(rgb, K, centre, side * f, roll_rad, self.encoder, weights, self.settings.size,
                               hidden=hidden, coverage=coverage) for f in self.framing_starts]

    def _hidden(self, mask: np.ndarray, others: list[np.ndarray]) -> np.ndarray | None:
        """With :attr:`occluders`, the pixels of the ``others`` regions outside ``mask`` (None: none)."""
        if not self.occluders or not others:
            return None
        hidden = _union(others, mask.shape) & ~np.asarray(mask, bool)
        return hidden if hidden.any() else None

    def _pose(self, obj, rgb: np.ndarray, mask: np.ndarray, K: np.ndarray, others: list[np.ndarray]
              ) -> tuple[np.ndarray, np.ndarray, float, dict[str, Any]]:
        bank, weights = self.bank(obj)
        crops, q, qm, a, j, best = self.region_match(weights, rgb, mask, K)
        crop = crops[a]
        info: dict[str, Any] = {"template": int(j), "inplane_deg": float(np.degrees(self.inplane[a])),
                                "match": best}
        query, query_mask, roll = q[a], None if qm is None else qm[a], float(self.inplane[a])
        hidden, hidden_query = self._hidden(mask, others), None
        if self.framing:
            runs = self.framings(rgb, K, crop, float(self.inplane[a]), weights, hidden,
                                 None if hidden is None else template_coverage(bank))
            k = max(range(len(runs)), key=lambda i: (runs[i].score, -i))
            fr = runs[k]
            info.update(framing_crops=sum(r.crops for r in runs), framing_start=self.framing_starts[k],
                        match_region=best, match=fr.score,
                        inplane_deg=float(np.degrees(fr.roll_rad)))
            crop, j, best, query, query_mask, roll = fr.crop, fr.template, fr.score, fr.query, None, fr.roll_rad
            cells = hidden_cells(hidden, K, [crop], query.shape[-2:])
            hidden_query = None if cells is None else cells[0]
        if self.local_deg > 0:
            found, best, info["local_renders"] = local_search(
                self._renderer(obj), self.settings, self.encoder, query, query_mask, bank.R[j],
                best, step_deg=self.local_deg, min_step_deg=self.local_min_deg, hidden=hidden_query)
            if found is not None:
                bank, j, weights, info["match_local"] = found, 0, template_weights(found), best
        if self.polish > 0:
            fr = framing_search(rgb, K, window_centre(crop, K), crop.window[2], roll, self.encoder, weights[j:j + 1],
                                self.settings.size, shift=self.polish, scale=1.5 * self.polish,
                                roll_deg=100.0 * self.polish, min_shift=self.polish_min_shift)
            info.update(polish_crops=fr.crops, match_polish=fr.score, inplane_deg=float(np.degrees(fr.roll_rad)))
            crop, best = fr.crop, fr.score
        R, t = template_pose(bank, j, crop.K, crop.R_virt)
        t = t * self.depth_scale
        info["t_matched"] = t.tolist()
        if self.refine == "silhouette":
            if not crop.mask.any():  # a searched framing's crop carries no region: give it the region
                crop = replace(crop, mask=mask_in_crop(mask, K, crop))
            R, t, info["silhouette"] = self._refine(obj, R, t, crop, K, rgb.shape[:2], others)
        elif self.refine == "edges":
            if self._edges is None:  # one distance transform per image
                self._edges = edge_distance(rgb)
            fit = fit_edges(obj, R, t, K, self._edges)
            t = fit.t
            info["edges"] = {"applied": fit.applied, "cost_before": fit.cost_before, "cost_after": fit.cost_after,
                             "scale": fit.scale, "shift_px": [fit.du, fit.dv]}
        return R, t, best, info

    def _renderer(self, obj) -> ObjectRenderer:
        """``obj``'s template renderer (made at first use, kept)."""
        if obj.obj_id not in self.renderers:
            self.renderers[obj.obj_id] = ObjectRenderer(obj, render_intrinsics(obj, self.settings), RENDER_SIZE,
                                                        RENDER_SIZE)
        return self.renderers[obj.obj_id]

    def _refine(self, obj, R: np.ndarray, t: np.ndarray, crop, K: np.ndarray, shape: tuple[int, int],
                others: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
        """The pose fitted to the region's mask in the crop's camera, the other regions' pixels not counted."""
        from simtest.estimators.silhouette import fit_translation

        valid = crop.valid.copy()
        if others:
            valid &= ~mask_in_crop(_union(others, shape), K, crop)
        Rv = crop.R_virt
        fit = fit_translation(obj, Rv @ R, Rv @ t, crop.K, crop.mask.astype(np.float64), valid,
                              max_scale=self.refine_max_scale, step_deg=self.refine_deg,
                              min_step_px=self.refine_min_px)
        return Rv.T @ fit.R, Rv.T @ fit.t, {"applied": fit.applied, "iou_before": fit.iou_before,
                                             "iou_after": fit.iou_after, "scale": fit.scale}
