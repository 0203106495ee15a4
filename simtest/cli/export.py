"""``simtest export CHECKPOINT``: write a trained network's ONNX file, so it runs without torch."""

from __future__ import annotations

import argparse

from simtest.cli.common import common_parser


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "export", parents=[common_parser()],
        help="export a trained checkpoint (segmentation or keypoints) to ONNX for inference without torch "
             "(needs simtest[train])",
        description="Write the ONNX file of a checkpoint from `simtest train` (model.pt, best.pt, last.pt), by "
                    "default beside it (model.pt -> model.onnx). The file carries the checkpoint's object record "
                    "and settings; `simtest eval --estimator segicp|keypoints --opt checkpoint=...` then runs "
                    "it with ONNX Runtime, no torch needed. Training writes model.onnx and best.onnx itself.",
    )
    p.add_argument("checkpoint", help="a .pt checkpoint of simtest train segmentation|keypoints")
    p.add_argument("--out", metavar="FILE.onnx", help="ONNX file to write (default: beside the checkpoint)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing ONNX file")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from simtest.estimators.onnx_export import export_checkpoint
    from simtest.estimators.onnx_net import onnx_path_for

    out = args.out or onnx_path_for(args.checkpoint)
    path = export_checkpoint(args.checkpoint, out, overwrite=bool(args.overwrite))
    print(f"wrote {path}")
    return 0
