"""``simtest grasp``: closed-loop grasping episodes driven by a pose estimator, scored end to end."""

from __future__ import annotations

import argparse
import sys

from simtest.cli.common import LazyChoices, add_backend_options, add_fault_options, common_parser, locks_output
from simtest.errors import ConfigError, EstimatorError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "grasp", parents=[common_parser()], help="closed-loop Panda grasping driven by a pose estimator (success rate with 95%% CI)",
        description="Run closed-loop grasp episodes: the Panda's wrist camera observes the target, the estimator "
                    "estimates its pose, a grasp planned from that estimate is executed, and success (lifted "
                    ">= 0.10 m and held 1 s) is recorded. Writes episodes.csv, summary.json and summary.md "
                    "(see docs/grasping.md). The estimator gets the wrist camera's RGB-D image, its intrinsics, "
                    "the target's object id and the target's ground-truth visible mask and box (the 'GT "
                    "detections' protocol); see docs/plugins.md.")
    p.add_argument("--estimator", required=True,
                   help="estimator: a built-in or installed name (oracle, icp, ...), module:attr, or "
                        "path/to/file.py:attr")
    p.add_argument("--opt", action="append", default=[], metavar="KEY=VALUE",
                   help="estimator option (repeatable), parsed as for simtest eval; e.g. --opt trans_noise_mm=10")
    p.add_argument("--episodes", type=int, default=10, help="number of episodes (default 10)")
    p.add_argument("--objects", default=None,
                   help="object set: builtin, builtin-small, or a path (default: the estimator's own set when it "
                        "declares one, e.g. builtin-small for segicp's shipped checkpoint; else builtin)")
    p.add_argument("--units", default="auto", choices=["m", "cm", "mm", "auto"],
                   help="units of mesh files (auto: metres, refusing a diameter outside 1 cm .. 1.5 m)")
    p.add_argument("--scale", type=float, default=1.0, help="factor on top of --units (default 1)")
    p.add_argument("--target", default=None,
                   help="targets cycled over the episodes: comma-separated obj_ids or names, or 'all' (every "
                        "graspable object in turn); default a random graspable object per episode")
    p.add_argument("--distractors", type=int, default=0, help="distractor objects per scene (default 0)")
    p.add_argument("--occlusion", default="L0", choices=["L0", "L1", "L2", "L3"],
                   help="physical occluder level between the observation camera and the target")
    p.add_argument("--weather", default=None, help="image corruption of the observation (e.g. fog, snow)")
    p.add_argument("--severity", type=int, default=3, help="corruption severity 1..5 (default 3)")
    p.add_argument("--depth-noise", default=None, choices=LazyChoices("simtest.corrupt", "DEPTH_PRESETS"),
                   help="depth-noise preset of the observation (default: none)")
    p.add_argument("--depth-sensor", default="none", choices=["none", "d435-stereo", "passive-stereo"],
                   help="depth of the observation: none (the exact rendered depth, default) or a simulated stereo "
                        "sensor (IR pair, dot projector, SGBM): the estimator and the planner see its sensed depth")
    p.add_argument("--planner-obstacles", default="sim", choices=["sim", "observed"],
                   help="obstacles of the grasp planner's collision check: sim (the simulator's geometry of "
                        "distractors and occluders, default) or observed (only the points of the observation's "
                        "depth image, the target removed at its estimated pose; the table stays known)")
    p.add_argument("--width", type=int, default=320, help="wrist camera width, pixels (default 320)")
    p.add_argument("--height", type=int, default=None, help="wrist camera height (default 3/4 of the width)")
    p.add_argument("--seed", type=int, default=0, help="master seed; episode i uses SeedSequence child i")
    p.add_argument("--workers", type=int, default=1, help="worker processes (each owns whole episodes)")
    add_backend_options(p, "episode")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--overwrite", action="store_true", help="write into a non-empty --out, replacing its results")
    p.add_argument("--video", action="store_true", help="write third-person | wrist clips (GIF without ffmpeg)")
    p.add_argument("--video-episodes", type=int, default=5, help="how many episodes get a clip (default 5)")
    p.add_argument("--reobserve", default="none", metavar="none|pregrasp|approach:K",
                   help="look again on the way in: none (default), pregrasp (once at the pre-grasp pose) or "
                        "approach:K (K looks on the way there, then one at the pre-grasp pose); writes stages.csv "
                        "and a per-look pose-error table")
    p.add_argument("--reobserve-update", default="estimate", choices=["estimate", "track"],
                   help="how a new look updates the pose: the estimator again (default) or a tracker warm-started "
                        "from the pose so far (the estimator's own track() if it has one, else track-icp)")
    p.add_argument("--reobserve-fusion", default="mean", choices=["mean", "latest", "gated"],
                   help="how the looks are combined: mean of every look in the world frame (default), the latest, "
                        "or gated (the mean without looks more than 25 mm or 25 degrees from the pose so far)")
    p.add_argument("--task", default="single", choices=["single", "declutter"],
                   help="single: one target per episode (default); declutter: clutter removal rounds (objects "
                        "picked one after another until the table is clear; --episodes counts rounds)")
    p.add_argument("--scene", default="pile", choices=["pile", "packed"],
                   help="declutter scene: pile (dropped from a box) or packed (upright, side by side)")
    p.add_argument("--objects-per-scene", type=int, default=5, help="declutter: objects per round (default 5)")
    p.add_argument("--plain-looks", action="store_true",
                   help="draw scenes in the plain look of earlier releases (flat table, checker floor) instead of "
                        "the generator's materials, prints, environments and lights (default: the looks datasets "
                        "are drawn with; poses and masks are the same either way)")
    p.add_argument("--observation-profile", default="fast", choices=["fast", "quality", "pbr"],
                   help="how the wrist camera's captures are rendered: fast (rasterized, default), quality "
                        "(rasterized with shadows and MSAA) or pbr (the path tracer for the captured observations "
                        "only, about 1-3 s each; depth and masks from the rasterizer; needs the pbr extra)")
    p.add_argument("--save-observations", action="store_true",
                   help="write every episode's wrist captures as a BOP dataset in OUT/observations (scene = "
                        "episode; readable by simtest eval and simtest show)")
    add_fault_options(p, "episode", "an episode over it ends as 'estimator_timeout' and the run goes on",
                      "exit code 1 if the estimator failed in every episode")
    p.set_defaults(func=run)
    locks_output(p)


def _targets(text: str | None) -> tuple:
    if text is None:
        return ()
    parts = [t.strip() for t in text.split(",") if t.strip()]
    if not parts:
        raise ConfigError(f"--target must list obj_ids or names, or be 'all'; got {text!r}")
    if parts == ["all"]:
        return ("all",)
    return tuple(int(t) if t.isdigit() else t for t in parts)


def run(args: argparse.Namespace) -> int:
    from simtest.envs.runner import GraspRunConfig, run_grasp_episodes
    from simtest.estimators.options import parse_options
    from simtest.estimators.registry import check_estimator_options, default_object_set
    from simtest.io.files import prepare_out_dir

    prepare_out_dir(args.out, overwrite=args.overwrite)  # before anything is loaded
    options = parse_options(args.opt)
    check_estimator_options(args.estimator, options)  # before the robot and the objects are loaded
    objects = args.objects if args.objects is not None else default_object_set(args.estimator, options)

    cfg = GraspRunConfig(
        estimator=args.estimator, estimator_options=options, episodes=args.episodes,
        seed=args.seed, objects=objects, units=args.units, scale=args.scale, targets=_targets(args.target),
        n_distractors=args.distractors,
        occlusion=args.occlusion, weather=args.weather, severity=args.severity, depth_noise=args.depth_noise,
        depth_sensor=args.depth_sensor,
        width=args.width, height=args.height if args.height is not None else args.width * 3 // 4,
        workers=args.workers, backend=args.backend or "local", ray_address=args.ray_address, video=args.video,
        video_episodes=args.video_episodes, timeout=args.timeout,
        fail_fast=args.fail_fast, planner_obstacles=args.planner_obstacles,
        reobserve=args.reobserve, reobserve_update=args.reobserve_update, reobserve_fusion=args.reobserve_fusion,
        task=args.task, scene=args.scene, objects_per_scene=args.objects_per_scene,
        looks=not args.plain_looks, observation_profile=args.observation_profile,
        save_observations=args.save_observations)
    if cfg.task == "declutter":
        from simtest.envs.declutter import run_declutter

        result = run_declutter(cfg, args.out, progress=not args.quiet, command_line=["simtest", *sys.argv[1:]])
        print(result.table())
        print(f"wrote {args.out}/rounds.csv, attempts.csv, summary.json, summary.md")
        return 0
    try:
        report = run_grasp_episodes(cfg, args.out, progress=not args.quiet, overwrite=args.overwrite,
                                    command_line=["simtest", *sys.argv[1:]])
    except EstimatorError as exc:
        print(f"simtest grasp: estimator failed (--fail-fast): {exc}", file=sys.stderr)
        return 1
    if not args.quiet:
        print(report.run.summary(), file=sys.stderr)
    print(report.table())
    if "stages" in report.summary:
        from simtest.envs.reobserve import stage_markdown

        print(stage_markdown(report.summary["stages"]))
    print(f"wrote {args.out}/episodes.csv, summary.json, summary.md")
    if report.all_estimator_faults():
        print(f"simtest grasp: error: {report.failure_summary()}; see {args.out}/episodes.csv", file=sys.stderr)
        return 1
    if report.estimator_faults():
        print(f"simtest grasp: {report.failure_summary()}; see {args.out}/episodes.csv", file=sys.stderr)
    return 0
