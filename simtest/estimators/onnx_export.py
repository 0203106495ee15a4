"""Export a trained checkpoint to ONNX for torch-free inference (:mod:`simtest.estimators.onnx_net`).

Needs torch, onnx and onnxscript (the ``train`` extra): torch's dynamo exporter at opset 18, with dynamic
batch, height and width, batch norms folded. The same checkpoint gives the same file bytes. The network's
inputs and outputs:

* segmentation (``simtest-segmentation/1``): ``input`` (N, 3 or 4, H, W) float32 (RGB in [0, 1], then the
  relative depth channel), H and W multiples of 16 -> ``logits`` (N, C+1, H, W);
* keypoints (``simtest-keypoints/1``): ``input`` (N, 3, H, W) -> ``seg`` (N, C+1, H/4, W/4), ``offsets``
  (N, J, 2, H/4, W/4), ``conf_logit`` (N, J, H/4, W/4);
* keypoint crops (``simtest-keypoints/2``): ``input`` (N, 3, S, S) crops -> ``fg`` (N, C, S/4, S/4) mask logits,
  ``kp`` (N, C 3 J, S/4, S/4) per-class offsets and confidence logits and, for a dense network, ``xyz``
  (N, 4 C, S/4, S/4) object coordinates and their confidence logits
  (:class:`simtest.estimators.keypoints.crop_model.CropKeypointNet`);
* outlines (``simtest-outline/1``): ``input`` (N, 4, S, S) crops (RGB in [0, 1], then the pose's silhouette)
  -> ``logits`` (N, 1, S, S) visible-mask logits (:class:`simtest.estimators.templates.mask_model.MaskNet`).
"""

from __future__ import annotations

import json
import logging
import os
import warnings
from pathlib import Path
from typing import Any

from simtest.errors import ConfigError
from simtest.estimators.checkpoint import load_checkpoint
from simtest.estimators.onnx_net import ONNX_FORMAT, file_sha256, onnx_path_for

__all__ = ["export_checkpoint", "OPSET", "INSTALL_HINT"]

OPSET = 18
INSTALL_HINT = "pip install 'simtest[train]' (torch, onnx, onnxscript)"
_FORMATS = ("simtest-segmentation/1", "simtest-keypoints/1", "simtest-keypoints/2", "simtest-outline/1")


def _network(ckpt: dict[str, Any]):
    """The torch module of a checkpoint (eval mode), its example input and its output names."""
    import torch

    if ckpt["format"] == "simtest-segmentation/1":
        from simtest.estimators.segicp.model import SegNet, SegNetConfig

        net = SegNet(SegNetConfig.from_dict(ckpt["net"]))
        net.load_state_dict(ckpt["model"])
        cin = 4 if net.cfg.depth_input else 3
        h = 240 if net.cfg.backbone == "plain" else 256  # the EfficientNet encoder's sizes are multiples of 32
        return net.eval(), torch.rand(2, cin, h, 320, generator=torch.Generator().manual_seed(0)), ["logits"]
    if ckpt["format"] == "simtest-outline/1":
        from simtest.estimators.templates.mask_model import MaskNet, MaskNetConfig

        mask_net = MaskNet(MaskNetConfig.from_dict(ckpt["net"]))
        mask_net.load_state_dict(ckpt["model"])
        S = int(mask_net.cfg.crop_size)
        return mask_net.eval(), torch.rand(2, 4, S, S, generator=torch.Generator().manual_seed(0)), ["logits"]
    from simtest.estimators.keypoints.model import KeypointNet, NetConfig

    class _Tuple(torch.nn.Module):  # the exporter wants a tuple of outputs, the net returns a dict
        def __init__(self, inner: torch.nn.Module, keys: tuple[str, ...]) -> None:
            super().__init__()
            self.inner, self.keys = inner, keys

        def forward(self, x: torch.Tensor):
            out = self.inner(x)
            return tuple(out[k] for k in self.keys)

    if ckpt["format"] == "simtest-keypoints/2":
        from simtest.estimators.keypoints.crop_model import CropKeypointNet, CropNetConfig

        crop_net = CropKeypointNet(CropNetConfig.from_dict(ckpt["net"]))
        crop_net.load_state_dict(ckpt["model"])
        S = int(crop_net.cfg.crop_size)
        example = torch.rand(2, 3, S, S, generator=torch.Generator().manual_seed(0))
        names = ["fg", "kp"] + (["xyz"] if crop_net.cfg.dense else [])
        return _Tuple(crop_net.eval(), tuple(names)).eval(), example, names

    net = KeypointNet(NetConfig.from_dict(ckpt["net"]))
    net.load_state_dict(ckpt["model"])
    example = torch.rand(2, 3, 240, 320, generator=torch.Generator().manual_seed(0))
    return _Tuple(net.eval(), ("seg", "offsets", "conf_logit")).eval(), example, ["seg", "offsets", "conf_logit"]


def export_checkpoint(checkpoint: str | Path, out: str | Path | None = None, overwrite: bool = True) -> Path:
    """Write the ONNX file of a segmentation or keypoint checkpoint (default: beside it, ``model.onnx``).

    Args:
        checkpoint: A ``.pt`` file from ``simtest train`` (``model.pt``, ``best.pt``, ``last.pt``).
        out: The ``.onnx`` file to write (atomically).
        overwrite: Replace an existing file (``simtest export`` asks for ``--overwrite``).

    Raises:
        ConfigError: torch / onnx / onnxscript missing, an unreadable checkpoint or one of another kind, or
            ``out`` exists without ``overwrite``.
    """
    try:
        import onnxscript  # noqa: F401
        import torch
        from torch.export import Dim
    except ImportError as exc:
        raise ConfigError(f"exporting to ONNX needs torch, onnx and onnxscript ({exc}): {INSTALL_HINT}") from None
    checkpoint = Path(checkpoint)
    out = onnx_path_for(checkpoint) if out is None else Path(out)
    if out.suffix != ".onnx":
        raise ConfigError(f"the ONNX file must end in .onnx, got {str(out)!r}")
    if out.exists() and not overwrite:
        raise ConfigError(f"{str(out)!r} exists; pass --overwrite to replace it")
    fmt = None
    for f in _FORMATS:
        try:
            ckpt = load_checkpoint(checkpoint, fmt=f)
            fmt = f
            break
        except ConfigError as exc:
            if "not a" not in str(exc):
                raise
    if fmt is None:
        raise ConfigError(f"{checkpoint}: not a segmentation, keypoint or outline checkpoint of simtest train")
    net, example, names = _network(ckpt)
    dims = {0: Dim("batch", min=1, max=64), 2: Dim("height", min=16, max=4096), 3: Dim("width", min=16, max=4096)}
    if fmt == "simtest-outline/1":  # crops of the network's one size
        dims = {0: Dim("batch", min=1, max=64)}
    quiet = logging.getLogger("torch.onnx")
    level = quiet.level
    quiet.setLevel(logging.ERROR)  # "torchvision is not installed. Skipping ..." per export
    with warnings.catch_warnings(), torch.inference_mode(False):
        warnings.simplefilter("ignore")
        program = torch.onnx.export(net, (example,), dynamo=True, opset_version=OPSET, input_names=["input"],
                                    output_names=names, dynamic_shapes={"x": dims}, optimize=True, verbose=False)
    quiet.setLevel(level)
    program.model.metadata_props.update({
        "simtest.onnx_format": ONNX_FORMAT, "simtest.format": fmt,
        "simtest.net": json.dumps(ckpt["net"], sort_keys=True),
        "simtest.objects": json.dumps(ckpt["objects"], sort_keys=True),
        "simtest.focal_px": repr(float(ckpt.get("focal_px", 0.0))), "simtest.epoch": str(int(ckpt.get("epoch", -1))),
        "simtest.source_sha256": file_sha256(checkpoint)})
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.tmp{os.getpid()}")
    try:
        program.save(str(tmp), external_data=False)
        os.replace(tmp, out)
    finally:
        if tmp.exists():
            tmp.unlink()
    return out
