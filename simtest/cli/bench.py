"""``simtest bench generate|pbr-quality|check|grasp|metrics|corruptions|panda|objects|backend|channels|stereo|appearance``: speed figures measured in the same run (ratios
against raw MuJoCo)."""

from __future__ import annotations

import argparse

from simtest.cli.common import common_parser


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("bench", help="speed benchmarks (ratios against raw MuJoCo in the same run)")
    bsub = p.add_subparsers(dest="bench_command", metavar="BENCH")
    g = bsub.add_parser("generate", parents=[common_parser()],
                        help="dataset generation frames/s vs raw MuJoCo rendering, CPU ms per frame; "
                             "1 vs 2 workers",
                        description="Dataset generation frames/s against raw MuJoCo rendering of the same scenes, "
                                    "CPU ms per frame, 1 vs 2 workers. The datasets are written under $TMPDIR: "
                                    "file creation costs differ between disks, so point it at the one your "
                                    "datasets go to.")
    g.add_argument("--width", type=int, default=640)
    g.add_argument("--height", type=int, default=480)
    g.add_argument("--objects-per-scene", type=int, default=10)
    g.add_argument("--scenes", type=int, default=8)
    g.add_argument("--frames-per-scene", "--views", dest="frames_per_scene", type=int, default=10,
                   help="views (frames) per settled scene (default 10; BOP's PBR recipe uses 25)")
    g.add_argument("--objects", default="builtin")
    g.add_argument("--no-workers", action="store_true", help="skip the 2-worker measurement")
    g.add_argument("--plain-looks", action="store_true",
                   help="without the material library, object prints and environment (materials.families = [], "
                        "materials.object_textures = false, lights.environment = constant), as earlier releases")
    g.add_argument("--profiles", help="instead: seconds per frame of these render profiles, 1 and 2 workers, "
                                      "e.g. fast,quality,pbr")
    g.add_argument("--sizes", help="image sizes for --profiles, e.g. 320x240,640x480 (default --width x --height)")
    g.add_argument("--pbr-spp", default="auto",
                   help="samples per pixel of the pbr profile (--profiles): an integer, or auto (default: 12 at "
                        "320x240, 6 at 640x480, as render.pbr_spp)")
    g.add_argument("--pbr-variant", default="auto", choices=["auto", "cuda", "llvm", "scalar"],
                   help="Mitsuba variant of the pbr profile (--profiles; default auto, as render.pbr_variant)")
    g.add_argument("--json", metavar="FILE", dest="json_out",
                   help="also write the table as JSON to FILE (with the cores and load average of the run; "
                        "`simtest bench check` compares such a file of a --profiles run with a fresh run)")
    g.add_argument("--channels", action="store_true",
                   help="also the milliseconds per frame of each dense ground-truth channel (generate --channels) "
                        "at --width x --height, as `simtest bench channels`")
    g.set_defaults(func=_generate)
    _register_pbr_quality(bsub)
    ck = bsub.add_parser("check", parents=[common_parser()],
                         help="a fresh `bench generate --profiles` run against the figures recorded in the "
                              "repository: fresh / recorded seconds per frame")
    ck.add_argument("--recorded", default=None,
                    help="recorded figures (default simtest/benchmarks/recorded.json)")
    ck.add_argument("--fresh", default=None, metavar="FILE",
                    help="compare this `bench generate --profiles ... --json` file instead of running anew")
    ck.add_argument("--tolerance", type=float, default=1.3,
                    help="largest fresh / recorded ratio that passes (default 1.3); exit status 1 above it")
    ck.add_argument("--measure", choices=["cpu", "wall"], default="cpu",
                    help="the ratio checked against --tolerance: CPU s/frame (default; moved less by other work "
                         "on the machine) or wall s/frame")
    ck.set_defaults(func=_check)
    gr = bsub.add_parser("grasp", parents=[common_parser()],
                         help="grasp env steps/s vs raw mj_step; oracle episode wall time; reset ms and RSS")
    gr.add_argument("--episodes", type=int, default=3)
    gr.add_argument("--resets", type=int, default=500,
                    help="random-target resets timed, RSS recorded after 5/50/100/500 (default 500; 0 skips)")
    gr.add_argument("--width", type=int, default=320)
    gr.add_argument("--height", type=int, default=240)
    gr.set_defaults(func=_grasp)
    m = bsub.add_parser("metrics", parents=[common_parser()],
                        help="milliseconds per call of each pose metric on a fixed synthetic model")
    m.add_argument("--number", type=int, default=5, help="calls per timing (default 5)")
    m.add_argument("--repeat", type=int, default=3, help="timings; the best is reported (default 3)")
    m.set_defaults(func=_metrics)
    c = bsub.add_parser("corruptions", parents=[common_parser()],
                        help="milliseconds per call of each ImageNet-C corruption on a 640x480 image")
    c.add_argument("--severity", type=int, default=4, help="severity 1..5 (default 4)")
    c.add_argument("--width", type=int, default=640)
    c.add_argument("--height", type=int, default=480)
    c.set_defaults(func=_corruptions)
    pa = bsub.add_parser("panda", parents=[common_parser()],
                         help="Panda model mj_step/s (at rest and moving) and one scripted grasp, no rendering")
    pa.add_argument("--steps", type=int, default=5000, help="mj_step calls per timing (default 5000)")
    pa.set_defaults(func=_panda)
    ob = bsub.add_parser("objects", parents=[common_parser()],
                         help="load time and first-scene time of a 20- vs a 200-object generated mesh library")
    ob.add_argument("--sizes", default="20,200", help="objects per set, comma-separated (default 20,200)")
    ob.add_argument("--categories", default="4,40", help="categories per set, comma-separated (default 4,40)")
    ob.add_argument("--width", type=int, default=320)
    ob.add_argument("--height", type=int, default=240)
    ob.add_argument("--objects-per-scene", type=int, default=5)
    ob.set_defaults(func=_objects)
    bk = bsub.add_parser("backend", parents=[common_parser()],
                         help="generate wall time: local 1 and 2 workers vs Ray 1 and 2 CPUs, Ray start-up")
    bk.add_argument("--width", type=int, default=640, help="image width in pixels (default 640)")
    bk.add_argument("--height", type=int, default=480, help="image height in pixels (default 480)")
    bk.add_argument("--scenes", type=int, default=24,
                    help="scenes per measurement (default 24; short jobs measure mostly start-up)")
    bk.add_argument("--frames-per-scene", type=int, default=25, help="views per scene (default 25)")
    bk.add_argument("--objects", default="builtin", help="object set (default builtin)")
    bk.set_defaults(func=_backend)
    ch = bsub.add_parser("channels", parents=[common_parser()],
                         help="milliseconds per frame of each dense ground-truth channel (generate --channels)")
    ch.add_argument("--width", type=int, default=640, help="image width in pixels (default 640)")
    ch.add_argument("--height", type=int, default=480, help="image height in pixels (default 480)")
    ch.add_argument("--scenes", type=int, default=2, help="scenes (default 2)")
    ch.add_argument("--frames-per-scene", type=int, default=5, help="sequence views per scene (default 5)")
    ch.add_argument("--objects", default="builtin", help="object set (default builtin)")
    ch.set_defaults(func=_channels)
    st = bsub.add_parser("stereo", parents=[common_parser()],
                         help="milliseconds per view of a simulated stereo depth sensor against the fast profile's "
                              "frame (generate --depth-sensor)")
    st.add_argument("--width", type=int, default=640, help="image width in pixels (default 640)")
    st.add_argument("--height", type=int, default=480, help="image height in pixels (default 480)")
    st.add_argument("--preset", default="d435-stereo", help="sensor preset (default d435-stereo)")
    st.add_argument("--views", type=int, default=3, help="views of one generated scene (default 3)")
    st.set_defaults(func=_stereo)
    ap = bsub.add_parser("appearance", parents=[common_parser()],
                         help="rg-chromaticity spread inside the objects' visible masks of a dataset (flat-coloured "
                              "objects about 0.02, printed or textured ones 0.04-0.2)")
    ap.add_argument("dataset", help="BOP dataset folder")
    ap.add_argument("--split", default=None, help="split folder (default: the dataset's only split)")
    ap.set_defaults(func=_appearance)
    p.set_defaults(func=lambda args: (p.print_help(), 2)[1])


def _register_pbr_quality(bsub) -> None:
    """``simtest bench pbr-quality`` (:mod:`simtest.benchmarks.pbr_quality`)."""
    pq = bsub.add_parser("pbr-quality", parents=[common_parser()],
                         help="pbr settings: seconds per frame and PSNR against a high-sample reference of the same "
                              "views (looks on)",
                         description="Seconds per frame and PSNR (dB) against a reference of the same views for "
                                     "each pbr setting, views interleaved so that load drift weighs on all alike. "
                                     "A setting: before, default, or NAME:key=value,... with keys spp (integer, "
                                     "auto, previous), sampler, guide_spp, denoise_quality, freeze (0 or 1).")
    pq.add_argument("--sizes", default="320x240,640x480", help="image sizes (default 320x240,640x480)")
    pq.add_argument("--settings", default="before;default",
                    help="settings separated by ';' (default 'before;default': the earlier and this release's "
                         "defaults), e.g. 'default;hq:denoise_quality=high'")
    pq.add_argument("--scenes", type=int, default=2, help="scenes per size (default 2)")
    pq.add_argument("--views", type=int, default=3, help="views per scene (default 3)")
    pq.add_argument("--reference-spp", type=int, default=512,
                    help="samples per pixel of the reference (default 512; denoised)")
    pq.add_argument("--cache", default=None, metavar="DIR",
                    help="keep the references here and reuse them in later runs (default: not kept)")
    pq.add_argument("--seed", type=int, default=0, help="seed of the scenes (default 0)")
    pq.add_argument("--json", metavar="FILE", dest="json_out", help="also write the table as JSON to FILE")
    pq.set_defaults(func=_pbr_quality)


def _appearance(args: argparse.Namespace) -> int:
    from simtest.benchmarks.appearance import chromaticity_spread

    res = chromaticity_spread(args.dataset, args.split)
    print("| measurement | value |\n|---|---|")
    for key, value in res.items():
        if isinstance(value, dict):  # per category: {"mean": ..., "instances": ...}
            value = ", ".join(f"{k} {v['mean']:.3f} ({v['instances']})" if isinstance(v, dict) else f"{k} {v}"
                              for k, v in value.items())
        elif isinstance(value, float):
            value = f"{value:.4f}"
        print(f"| {key} | {value} |")
    return 0


def _backend(args: argparse.Namespace) -> int:
    from simtest.benchmarks.backend import bench_backend

    res = bench_backend(args.width, args.height, args.scenes, args.frames_per_scene, args.objects)
    print(res.table())
    print(res.estimate())
    return 0


#: The generation values of the plain look (no material library, prints or environment).
PLAIN_LOOKS = {"materials.families": [], "materials.object_textures": False, "lights.environment": "constant"}


def _generate(args: argparse.Namespace) -> int:
    from simtest.benchmarks.generate import bench_generate

    if args.profiles:
        code = _profiles(args)
    else:
        looks = PLAIN_LOOKS if args.plain_looks else None
        res = bench_generate(args.width, args.height, args.objects_per_scene, args.scenes, args.frames_per_scene,
                             args.objects, two_workers=not args.no_workers, overrides=looks)
        print(res.table())
        _write_json(args, res.to_dict())
        code = 0
    if args.channels:
        print()
        _print_channels(args.width, args.height, 2, min(args.frames_per_scene, 5), args.objects)
    return code


def _sizes(text: str) -> list[tuple[int, int]]:
    """``WxH,WxH`` -> sizes; ConfigError naming the value."""
    from simtest.errors import ConfigError

    try:
        sizes = [tuple(int(v) for v in s.lower().split("x")) for s in text.split(",")]
    except ValueError:
        sizes = [()]
    if any(len(s) != 2 or min(s) < 1 for s in sizes):
        raise ConfigError(f"--sizes: expected WIDTHxHEIGHT[,WIDTHxHEIGHT...], got {text!r}")
    return sizes


def _pbr_quality(args: argparse.Namespace) -> int:
    from simtest.benchmarks.pbr_quality import bench_pbr_quality, parse_setting
    from simtest.errors import ConfigError

    settings = [parse_setting(t.strip()) for t in args.settings.split(";") if t.strip()]
    names = [s.name for s in settings]
    if not settings or len(set(names)) != len(names):
        raise ConfigError(f"--settings: expected distinct setting names, got {names}")
    if args.reference_spp < 1 or args.scenes < 1 or args.views < 1:
        raise ConfigError(f"--reference-spp, --scenes and --views must be >= 1, got {args.reference_spp}, "
                          f"{args.scenes}, {args.views}")
    res = bench_pbr_quality(settings, _sizes(args.sizes), args.scenes, args.views, args.reference_spp,
                            cache=args.cache, seed=args.seed)
    print(res.table())
    if args.json_out:
        from simtest.benchmarks.check import bench_record
        from simtest.io.files import atomic_write_json

        cmd = (f"simtest bench pbr-quality --sizes {args.sizes} --settings '{args.settings}' --scenes {args.scenes} "
               f"--views {args.views} --reference-spp {args.reference_spp} --seed {args.seed}")
        atomic_write_json(args.json_out, bench_record(res.to_dict(), cmd))
        print(f"\nwrote {args.json_out}")
    return 0


def _profiles(args: argparse.Namespace) -> int:
    from simtest.benchmarks.generate import bench_profiles
    from simtest.errors import ConfigError

    profiles = [p.strip() for p in args.profiles.split(",") if p.strip()]
    bad = [p for p in profiles if p not in ("fast", "quality", "pbr")]
    if bad or not profiles:
        raise ConfigError(f"--profiles: unknown profile(s) {bad}; choose from fast, quality, pbr")
    sizes = _sizes(args.sizes) if args.sizes else [(args.width, args.height)]
    spp = args.pbr_spp
    if spp != "auto":
        if not spp.isdigit() or not 1 <= int(spp) <= 65536:
            raise ConfigError(f"--pbr-spp: expected auto or an integer in [1, 65536], got {spp!r}")
        spp = int(spp)
    res = bench_profiles(profiles, sizes, args.objects_per_scene, args.scenes, args.frames_per_scene,
                         args.objects, pbr_spp=spp, pbr_variant=args.pbr_variant, two_workers=not args.no_workers)
    print(res.table())
    _write_json(args, res.to_dict())
    return 0


def _write_json(args: argparse.Namespace, table: dict) -> None:
    """``--json FILE``: the table with the run's command (its measurement options), cores and load average."""
    if getattr(args, "json_out", None):
        from simtest.benchmarks.check import bench_record
        from simtest.io.files import atomic_write_json

        opts = [f"--profiles {args.profiles}", f"--sizes {args.sizes}" if args.sizes else
                f"--width {args.width} --height {args.height}"] if args.profiles else [
            f"--width {args.width} --height {args.height}"]
        opts += [f"--scenes {args.scenes}", f"--views {args.frames_per_scene}", f"--objects {args.objects}",
                 f"--objects-per-scene {args.objects_per_scene}"] + (["--no-workers"] if args.no_workers else [])
        atomic_write_json(args.json_out, bench_record(table, " ".join(["simtest bench generate", *opts])))
        print(f"\nwrote {args.json_out}")


def _check(args: argparse.Namespace) -> int:
    from simtest.benchmarks.check import RECORDED, check_table, compare, fresh_record, read_record

    recorded = read_record(args.recorded or RECORDED)
    fresh = read_record(args.fresh) if args.fresh else fresh_record(recorded)
    rows = compare(recorded, fresh, args.tolerance, args.measure)
    print(check_table(rows, recorded, fresh, args.tolerance, args.measure))
    return 1 if any(r.ok is False for r in rows) else 0


def _grasp(args: argparse.Namespace) -> int:
    from simtest.benchmarks.grasp import bench_grasp
    from simtest.errors import ConfigError

    if args.resets < 0:
        raise ConfigError(f"--resets must be >= 0 (0 skips the reset benchmark), got {args.resets}")
    print(bench_grasp(episodes=args.episodes, width=args.width, height=args.height, resets=args.resets).table())
    return 0


def _metrics(args: argparse.Namespace) -> int:
    from simtest.benchmarks.metrics import run, table

    print(table(run(args.number, args.repeat)))
    return 0


def _corruptions(args: argparse.Namespace) -> int:
    from simtest.benchmarks.corruptions import run, table

    print(table(run(args.width, args.height, args.severity)))
    return 0


def _channels(args: argparse.Namespace) -> int:
    _print_channels(args.width, args.height, args.scenes, args.frames_per_scene, args.objects)
    return 0


def _stereo(args: argparse.Namespace) -> int:
    from simtest.benchmarks.stereo import run, table

    print(f"{args.preset}, {args.width}x{args.height}, {args.views} views (best of 3 per view): "
          f"{table(run(args.width, args.height, args.preset, views=args.views))}")
    return 0


def _print_channels(width: int, height: int, scenes: int, views: int, objects: str) -> None:
    from simtest.benchmarks.channels import bench_channels

    res = bench_channels(width, height, scenes, views, objects=objects)
    print(f"dense channels, {res['width']}x{res['height']}, {res['frames']} frames, objects {objects}: "
          "median ms per frame (computed and PNG-encoded; writing runs on the writer threads; annotation is what "
          "every frame pays anyway)")
    print("| channel | ms / frame |\n|---|---:|")
    for name, ms in res["ms_per_frame"].items():
        print(f"| {name} | {ms:.1f} |")


def _objects(args: argparse.Namespace) -> int:
    from simtest.benchmarks.objects import bench_objects
    from simtest.errors import ConfigError

    try:
        sizes = tuple(int(v) for v in args.sizes.split(","))
        cats = tuple(int(v) for v in args.categories.split(","))
    except ValueError:
        raise ConfigError(f"--sizes and --categories must be comma-separated integers, got {args.sizes!r} and "
                          f"{args.categories!r}") from None
    if len(sizes) != len(cats) or len(sizes) < 2 or not all(1 <= c <= n for n, c in zip(sizes, cats)):
        raise ConfigError(f"--sizes and --categories need two or more entries each, with 1 <= categories <= "
                          f"objects, got {args.sizes!r} and {args.categories!r}")
    print(bench_objects(sizes, cats, args.width, args.height, args.objects_per_scene).table())
    return 0


def _panda(args: argparse.Namespace) -> int:
    from simtest.benchmarks.panda import benchmark, table

    print(table(benchmark(args.steps)))
    return 0
