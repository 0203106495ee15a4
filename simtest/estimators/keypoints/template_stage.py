"""The ``keypoints`` estimator's template pose stage (``pose=templates``): its settings and the estimator they make.

The stage poses the detector's regions by template matching
(:class:`~simtest.estimators.templates.estimator.TemplateEstimator`), sharing the keypoint estimator's detectors.
Its settings were chosen on the real LM-O frames (docs/sim2real.md): per expected instance
:data:`TEMPLATE_CANDIDATES` regions, the best template match kept; no silhouette fit to the detector's coarse
regions; the framing search, which frees the pose from the region's outline, started from the region's window
scaled by each factor of :data:`TEMPLATE_FRAMING_STARTS`, the best match kept (1 and 1.4: the detectors' regions on
real frames often hold only part of their object, on renders the whole; on the 100 real LM-O frames 27.7 %
ADD(-S)-0.1d and AR_MSSD 0.349, against 25.5 % and 0.331 from 1.4 alone and 24.8 % and 0.307 from 1 alone, twelfth
and thirteenth rounds); besides the class map's regions, those of class probability above
:data:`TEMPLATE_REGION_EXTRA` that overlap none of them (0.2: 29.0 % and AR_MSSD 0.360 against 27.7 % and 0.349
without, fourteenth round; 0.05: 31.9 % and 0.387 against 30.0 % and 0.371 with 0.2, eighteenth round); the local
template search around the best match (first step :data:`TEMPLATE_LOCAL_DEG` degrees); the outline fit to the
shipped outline networks' probability at temperature 2 averaged with its mirror image's
(:func:`~simtest.estimators.templates.outline.shipped_outline`: for LM-O two networks that draw the whole
silhouette, hidden parts too, their probabilities averaged; 30.0 % and AR_MSSD 0.371 against 29.0 % and 0.360 with
one that draws the visible pixels, seventeenth round). The other objects' regions are not left out of the template
scores (:data:`TEMPLATE_OCCLUDERS`; left out, 62 against 62 of 187 targets on the first 25 frames, nineteenth round).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from simtest.estimators.templates.estimator import TemplateEstimator

__all__ = ["TEMPLATE_CANDIDATES", "TEMPLATE_SELECT", "TEMPLATE_REFINE", "TEMPLATE_FRAMING", "TEMPLATE_LOCAL_DEG",
           "TEMPLATE_OUTLINE_MASK", "TEMPLATE_OUTLINE_TEMPERATURE", "TEMPLATE_FRAMING_STARTS", "TEMPLATE_REGION_EXTRA",
           "TEMPLATE_OCCLUDERS", "TEMPLATE_LOCAL_MIN_DEG", "template_stage", "TemplatePoseStage"]

TEMPLATE_CANDIDATES, TEMPLATE_SELECT, TEMPLATE_REFINE, TEMPLATE_FRAMING = 3, "match", "none", True
TEMPLATE_LOCAL_DEG, TEMPLATE_OUTLINE_MASK, TEMPLATE_OUTLINE_TEMPERATURE = 4.0, "soft+flip", 2.0
#: Factors of the region's window side the framing search starts from (the best-matching result is kept).
TEMPLATE_FRAMING_STARTS: tuple[float, ...] = (1.0, 1.4)
#: Class probability above which regions the class map misses become candidates too (0: none; fourteenth and
#: eighteenth rounds).
TEMPLATE_REGION_EXTRA = 0.05
#: Last step of the local template search (degrees). 2 (the 4 and 2 degree steps only) scored as 1 on the real frames
#: (235 against 234 of 734) with 16 % less time per frame, short of the quarter its rule asked (twentieth round).
TEMPLATE_LOCAL_MIN_DEG = 1.0
#: Whether other objects' regions are left out of the framing and local searches' scores.
TEMPLATE_OCCLUDERS = False


def template_stage(detect: str, region_rank: str, objects: Any, options: dict[str, Any]) -> TemplateEstimator:
    """The template estimator of the stage for ``detect`` (``rgb`` or ``gt``) and ``region_rank``, with the
    keypoint estimator's ``options`` (``candidates``, ``outline``, ``outline_mask``, ``outline_temperature``,
    ``framing_starts``, ``region_extra``, ``occluders``, ``threads``; None: this module's settings). Without an ``outline`` option and with
    ``detect=rgb`` the shipped outline network for ``objects`` is taken, if there is one."""
    from simtest.estimators.templates.estimator import TemplateEstimator  # local: it imports the crop geometry
    from simtest.estimators.templates.outline import shipped_outline

    given, outline, starts = options["candidates"], options["outline"], options["framing_starts"]
    extra, occluders = options["region_extra"], options["occluders"]
    rgb = detect == "rgb"
    if outline is None:
        outline = shipped_outline(objects) if rgb else None
    return TemplateEstimator(
        detect=detect, region_rank=region_rank, threads=options["threads"] or 1,
        candidates=TEMPLATE_CANDIDATES if given is None else int(given), select=TEMPLATE_SELECT,
        refine=TEMPLATE_REFINE if rgb else "silhouette", framing=TEMPLATE_FRAMING and rgb,
        framing_starts=TEMPLATE_FRAMING_STARTS if starts is None else starts,
        region_extra=(TEMPLATE_REGION_EXTRA if extra is None else float(extra)) if rgb else 0.0,
        local_deg=TEMPLATE_LOCAL_DEG if rgb else 0.0, local_min_deg=TEMPLATE_LOCAL_MIN_DEG,
        outline=outline, outline_mask=options["outline_mask"],
        outline_temperature=options["outline_temperature"],
        occluders=(TEMPLATE_OCCLUDERS if occluders is None else bool(occluders)) and rgb)


class TemplatePoseStage:
    """What the keypoint estimator does with ``pose=templates`` (its ``pose``, ``detect``, ``region_rank``,
    ``segmenter``, ``more_segmenters``, ``templates``, ``_options`` and ``check_objects`` are read): the stage
    made at first use, its set-up before the first image, the time it may take per image."""

    @property
    def time_limit_s(self) -> float | None:
        """Seconds one image may take: the template stage's with ``pose=templates`` (None: the default's)."""
        from simtest.estimators.templates.estimator import TemplateEstimator

        return TemplateEstimator.time_limit_s if self.pose == "templates" else None

    def prepare(self, objects: Any) -> None:
        """Once before the first image, outside its time limit: the networks chosen for ``objects`` and, with
        ``pose=templates``, the stage's template banks read or built (minutes with a cold cache)."""
        self.check_objects(objects)
        if self.pose == "templates":
            self._template_stage(objects).prepare(objects)

    def _template_stage(self, objects: Any) -> TemplateEstimator:
        """The template estimator of ``pose=templates`` (made at first use, sharing the detectors)."""
        if self.templates is None:
            self.templates = template_stage(self.detect, self.region_rank, objects, self._options)
            self.templates.segmenter, self.templates.more_segmenters = self.segmenter, self.more_segmenters
        return self.templates

    def _template_poses(self, obs) -> list:
        """``pose=templates``: the detector's regions (or the ground-truth masks with ``detect=gt``) posed by
        template matching (:meth:`_template_stage`)."""
        out = self._template_stage(obs.objects).estimate(obs)
        self.last_failures = list(self.templates.last_failures)
        return out
