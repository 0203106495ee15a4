"""The recorder: a built, settled scene turned into views, every file handed to the scene's writer.

Per view it places the render camera (and, for the wrist rig, the arm), stands the physical occluder, renders
(the rasterizer; the path tracer's RGB for the ``pbr`` profile; a depth sensor's image), annotates, computes the
dense channels and gives all of it to :class:`~simtest.io.bop.SceneWriter`, which alone owns the scene folder and
the file encodings. Annotating and handing over run on a helper thread while the next view renders
(:class:`~simtest.generators.views_behind.ViewsBehind`). The scene's camera is the one its builder made
(``scene.camera``): intrinsics and image size in pixels, a pose in metres per view.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from simtest.camera import CameraModel
from simtest.generators.aiming import weighted_part
from simtest.generators.annotate import amodal_counts, annotate
from simtest.generators.builder import SimScene
from simtest.generators.config import GenerateConfig
from simtest.generators.dense import DenseViews
from simtest.generators.occlusion import measured_level, occlude_view
from simtest.generators.views_behind import ViewsBehind
from simtest.io.bop import SceneWriter

__all__ = ["SceneRecorder", "scene_cameras", "pbr_renderer", "OCCLUSION_FILE", "INFO_FILE"]

#: Per-view records of the physical occluder (``occlusion.level`` set).
OCCLUSION_FILE = "scene_occlusion.json"
#: How the scene was made: attempts, removed instances, settling, its spec.
INFO_FILE = "scene_info.json"


def scene_cameras(cfg: GenerateConfig, scene: SimScene) -> list[tuple[CameraModel, np.ndarray | None]]:
    """Every view of a settled scene: its camera (``scene.camera`` at an OpenCV ``T_world_cam``) and, for the
    wrist rig, the arm configuration (rad) that puts the wrist camera there (``None`` otherwise)."""
    from simtest.generators.scene_spec import view_to_camera_pose

    base = scene.camera
    pts = np.array([scene.data.xpos[b] for b, a in zip(scene.instance_bodies, scene.active) if a])
    poi = pts.mean(axis=0)
    poi[2] = max(poi[2], cfg.scene.table_height)
    if cfg.rig == "wrist":
        from simtest.generators.wrist import wrist_cameras

        return wrist_cameras(cfg, scene, poi, base)
    return [(base.with_pose(view_to_camera_pose(v, poi)), None) for v in scene.spec.views]


def pbr_renderer(cfg: GenerateConfig, scene: SimScene):
    """The path tracer of the ``pbr`` profile for ``scene`` (this worker's share of the cores), or ``None`` for
    the rasterized profiles."""
    if cfg.render.profile != "pbr":
        return None
    from simtest.backend.threads import worker_threads
    from simtest.render.pbr import PbrRenderer

    env = scene.spec.environment
    if env is not None:
        from simtest.generators.looks import environment_of

        env = (environment_of(env).radiance, env.strength)
    return PbrRenderer(scene.model, scene.camera, spp=cfg.render.pbr_spp, denoise=cfg.render.pbr_denoise,
                       threads=worker_threads(cfg.workers, cfg.ray_address).cores, variant=cfg.render.pbr_variant,
                       environment=env, sampler=cfg.render.pbr_sampler, guide_spp=cfg.render.pbr_guide_spp,
                       denoise_quality=cfg.render.pbr_denoise_quality)


class SceneRecorder:
    """Records the views of one scene into its writer.

    Args:
        cfg: The run's config (rig, render profile, depth sensor, occlusion, channels, captions).
        objects: The object set the scene was built from.
        scene: The built, settled scene (``scene.rng`` continues its stream: occluder levels).
        writer: The scene's writer; every file goes to it.
        scene_id: The scene's index (seeds of the path tracer and the depth sensor).
    """

    def __init__(self, cfg: GenerateConfig, objects, scene: SimScene, writer: SceneWriter, scene_id: int) -> None:
        self.cfg, self.objects, self.scene, self.writer, self.scene_id = cfg, objects, scene, writer, scene_id
        channels = cfg.annotation.channels
        self.dense = DenseViews(channels, scene.model, objects) if channels else None
        if self.dense is not None and self.dense.keypoint_counts is not None:
            writer.keypoint_counts = self.dense.keypoint_counts
        self.occlusion_log: dict[str, dict] = {}

    def record(self, cameras: list[tuple[CameraModel, np.ndarray | None]], finish_behind: bool = True) -> None:
        """Render, annotate and write every view of ``cameras`` (:func:`scene_cameras`), then the scene's
        occlusion records.

        Args:
            finish_behind: Annotate and write each view on a helper thread while the next one renders;
                ``False`` finishes each view before the next (the same files, one thread).
        """
        from simtest.render.rasterizer import Renderer

        cfg, scene = self.cfg, self.scene
        sensor = None
        if cfg.render.depth_sensor != "none":
            from simtest.sensors.stereo import stereo_preset

            sensor = stereo_preset(cfg.render.depth_sensor)
        pbr = pbr_renderer(cfg, scene)  # the pbr profile: path-traced RGB; depth and masks stay exact (fast path)
        with Renderer(scene.model, scene.camera.width, scene.camera.height,
                      profile="fast" if pbr is not None else cfg.render.profile) as renderer, \
                ViewsBehind(threaded=finish_behind) as behind:
            for im_id, (cam, arm_q) in enumerate(cameras):
                if arm_q is not None:
                    scene.set_arm(arm_q)
                scene.set_camera(cam)
                record = self._occlude(cam, renderer)
                frame = self._render(renderer, pbr, im_id)
                sensed = None
                if sensor is not None:  # renders through the same renderer, restores the camera; frame stays exact
                    from simtest.sensors.stereo import sensor_rng

                    sensed = sensor.sense(renderer, scene.data, scene.camera_id, cam,
                                          sensor_rng(cfg.seed, self.scene_id, im_id))
                behind.submit(self.finish_view, im_id, frame, cam, scene.state(), record, sensed)
        if self.occlusion_log:
            self.writer.write_json(OCCLUSION_FILE, self.occlusion_log, keyed=True)

    def _occlude(self, cam: CameraModel, renderer):
        """Stand the physical occluder for this view (``occlusion.level`` set); its record, or ``None``."""
        occ = self.cfg.occlusion
        if not occ.physical:
            return None
        scene = self.scene
        level, band = occ.level, None
        if level == "mixed":
            level = ("L0", "L1", "L2", "L3")[int(scene.rng.integers(4))]
        if occ.visib_band is not None:  # a visible-fraction band: the occluded-fraction band it means
            lo, hi = weighted_part(scene.rng, occ.visib_band, occ.visib_weights)
            level, band = f"visib {lo:.3g}-{hi:.3g}", (1.0 - hi, 1.0 - lo)
        return occlude_view(scene, cam, renderer, level, occ.definition, amodal_counts(scene, cam, self.objects),
                            self.cfg.scene.table_height, scene.rng, occ.standing_first, band=band)

    def _render(self, renderer, pbr, im_id: int):
        """The view's frame: the rasterizer's depth and segmentation, the RGB of the path tracer or its own."""
        scene = self.scene
        frame = renderer.render(scene.data, scene.camera_id, rgb=pbr is None)
        if pbr is not None:
            from simtest.render.pbr import frame_seed

            rgb = pbr.render(scene.data, scene.camera_id, seed=frame_seed(self.cfg.seed, self.scene_id, im_id)).rgb
            frame = dataclasses.replace(frame, rgb=rgb)
        return frame

    def finish_view(self, im_id: int, frame, cam: CameraModel, state, record, sensed=None) -> None:
        """Annotate a rendered view from the scene's state when it was rendered and hand it to the writer
        (``sensed``: a depth sensor's image for ``depth/``, the exact one then goes to ``depth_exact/``)."""
        writer, dense = self.writer, self.dense
        anns = annotate(state, frame, cam, self.objects)
        images, kps = dense.view(im_id, frame, cam, state, anns) if dense is not None else (None, None)
        flow = dense.take_flow() if dense is not None else None
        if flow is not None:  # the previous view's flow, finished by this one
            writer.add_image("flow", *flow)
        writer.add(im_id, frame.rgb, frame.depth if sensed is None else sensed, cam, anns, [a.mask for a in anns],
                   [a.mask_visib for a in anns], images=images, keypoints=kps)
        if sensed is not None:
            writer.add_depth("depth_exact", im_id, frame.depth)
        if record is not None:
            self.occlusion_log[str(im_id)] = record.to_dict(
                {a.instance: j for j, a in enumerate(anns)},
                [measured_level(1.0 - a.visib_fract, self.cfg.occlusion.definition) for a in anns])

    def write_records(self, settled, attempts: int, reasons: list[str], camera: CameraModel) -> None:
        """The scene's records after its views: :data:`INFO_FILE` (attempts, settling, spec) and, with
        ``captions``, its referring expressions from the settled poses and the first view's ``camera``."""
        scene = self.scene
        self.writer.write_json(INFO_FILE, {
            "scene_id": self.scene_id, "attempts": attempts, "retry_reasons": reasons,
            "removed_instances": list(settled.removed), "settle_time_s": settled.sim_time, "at_rest": settled.at_rest,
            "spec": scene.spec.to_dict()})
        if self.cfg.captions:
            from simtest.generators.captions import CAPTIONS_FILE, scene_captions

            self.writer.write_json(CAPTIONS_FILE, scene_captions(scene, self.objects, camera,
                                                                 self.cfg.scene.table_height))
