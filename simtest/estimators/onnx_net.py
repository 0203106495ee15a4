"""Learned networks at inference time without torch: an ONNX file run by ONNX Runtime on the CPU.

``simtest train`` writes ``model.onnx`` (and ``best.onnx``) beside its checkpoints and ``simtest export
CHECKPOINT`` converts any checkpoint (:mod:`simtest.estimators.onnx_export`, torch). The ONNX file describes
itself: its metadata carries what the checkpoint carried for inference, each value a string::

    simtest.onnx_format   "simtest-onnx/1" (this layout)
    simtest.format        the checkpoint's format ("simtest-segmentation/1", "simtest-keypoints/1")
    simtest.net           the network config (JSON)
    simtest.objects       the object record the network was trained for (JSON)
    simtest.focal_px      median focal length of the training images (pixels; segmentation)
    simtest.epoch         the checkpoint's last finished epoch
    simtest.source_sha256 SHA-256 of the checkpoint file it was exported from

so an estimator reads the ONNX file alone. Why ONNX Runtime: on this project's networks it gives the torch
outputs to ~1e-5 (logits) with identical argmax labels, identical outputs for 1 and 2 threads and for new
sessions, and runs 1.3-1.5x faster than torch and 1.2-1.7x faster than OpenCV's DNN module on 2 CPU cores
(measurements in docs/training.md).
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

import numpy as np

from simtest.errors import ConfigError

__all__ = ["OnnxNet", "resolve_runtime", "check_device", "RUNTIMES", "ONNX_FORMAT", "onnx_path_for", "file_sha256", "softmax", "softplus", "INSTALL_HINT"]

#: Layout of the metadata this module reads (see the module doc).
ONNX_FORMAT = "simtest-onnx/1"
INSTALL_HINT = "pip install onnxruntime"


def onnx_path_for(checkpoint: str | Path) -> Path:
    """The ONNX file that belongs to a checkpoint: same folder and stem (``model.pt`` -> ``model.onnx``)."""
    return Path(checkpoint).with_suffix(".onnx")


def file_sha256(path: str | Path) -> str:
    """Hex SHA-256 of a file's bytes."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def softmax(x: np.ndarray, axis: int) -> np.ndarray:
    """Numerically stable softmax along ``axis`` (float32 in, float32 out)."""
    e = np.exp(x - x.max(axis, keepdims=True))
    return e / e.sum(axis, keepdims=True)


def softplus(x: np.ndarray) -> np.ndarray:
    """``log(1 + exp(x))`` without overflow."""
    return np.logaddexp(0.0, x)


class OnnxNet:
    """One exported network: an ONNX Runtime session on the CPU and the file's simtest metadata.

    Args:
        path: The ``.onnx`` file.
        fmt: The checkpoint format the file must carry (``simtest-segmentation/1``, ...).
        threads: Intra-op threads (None: 1, so that generation and evaluation workers share the cores; the
            outputs are the same for any thread count).

    Raises:
        ConfigError: onnxruntime missing, a missing or unreadable file, or a file of another format.
    """

    def __init__(self, path: str | Path, fmt: str, threads: int | None = None) -> None:
        try:
            import onnxruntime as ort
        except ImportError as exc:  # pragma: no cover - a core dependency
            raise ConfigError(f"running {Path(path).name} needs ONNX Runtime: {INSTALL_HINT}") from exc
        self.path = Path(path)
        if not self.path.is_file():
            raise ConfigError(f"ONNX file {str(self.path)!r} does not exist")
        so = ort.SessionOptions()
        so.intra_op_num_threads = 1 if threads is None else max(1, int(threads))
        so.inter_op_num_threads = 1
        so.add_session_config_entry("session.intra_op.allow_spinning", "0")  # shared cores: do not busy-wait
        so.log_severity_level = 3
        try:
            self.session = ort.InferenceSession(str(self.path), so, providers=["CPUExecutionProvider"])
        except Exception as exc:  # noqa: BLE001 - any parse failure is a bad file
            raise ConfigError(f"ONNX file {str(self.path)!r} could not be read: {type(exc).__name__}: "
                              f"{' '.join(str(exc).split())[:300]}") from None
        self.meta = self._metadata(self.session.get_modelmeta().custom_metadata_map, fmt)
        self.input_name = self.session.get_inputs()[0].name
        self.output_names = [o.name for o in self.session.get_outputs()]

    def _metadata(self, raw: dict[str, str], fmt: str) -> dict[str, Any]:
        if raw.get("simtest.onnx_format") != ONNX_FORMAT:
            raise ConfigError(f"{self.path}: not a simtest ONNX file (simtest.onnx_format "
                              f"{raw.get('simtest.onnx_format')!r}, expected {ONNX_FORMAT!r}); export a checkpoint "
                              "with: simtest export CHECKPOINT")
        if raw.get("simtest.format") != fmt:
            raise ConfigError(f"{self.path}: a network of format {raw.get('simtest.format')!r}, expected {fmt!r}")
        return {"format": raw["simtest.format"], "net": json.loads(raw["simtest.net"]),
                "objects": json.loads(raw["simtest.objects"]), "focal_px": float(raw.get("simtest.focal_px", 0)),
                "epoch": int(raw.get("simtest.epoch", -1)), "source_sha256": raw.get("simtest.source_sha256", "")}

    @staticmethod
    def source_of(path: str | Path) -> str:
        """The ``simtest.source_sha256`` of an ONNX file ("" if it has none or cannot be read)."""
        try:
            import onnxruntime as ort

            so = ort.SessionOptions()
            so.log_severity_level = 3
            meta = ort.InferenceSession(str(path), so, providers=["CPUExecutionProvider"]).get_modelmeta()
            return str(meta.custom_metadata_map.get("simtest.source_sha256", ""))
        except Exception:  # noqa: BLE001 - unreadable counts as not current
            return ""

    def run(self, x: np.ndarray) -> list[np.ndarray]:
        """The network's outputs (in the file's output order) for one float32 NCHW batch."""
        return self.session.run(self.output_names, {self.input_name: np.ascontiguousarray(x, np.float32)})

    def __repr__(self) -> str:
        return f"OnnxNet({str(self.path)!r}, format={self.meta['format']!r})"


#: Ways to run a network: ``auto`` (the ONNX file when there is a current one, else torch), ``onnx``, ``torch``.
RUNTIMES = ("auto", "onnx", "torch")


def check_device(device: str, who: str) -> None:
    """Raise :class:`ConfigError` (naming ``who``) unless ``device`` is ``cpu``, ``cuda`` or ``cuda:N`` (where a
    torch network runs; ONNX Runtime runs on the CPU)."""
    if device not in ("cpu", "cuda") and not str(device).startswith("cuda:"):
        raise ConfigError(f"{who}: device must be cpu or cuda[:N], got {device!r}")


def resolve_runtime(path: Path, runtime: str, who: str) -> tuple[str, Path]:
    """``("onnx", file.onnx)`` or ``("torch", file.pt)`` for a checkpoint or ONNX ``path`` (see :data:`RUNTIMES`).

    A ``.pt`` runs through its ONNX file (same folder and stem) when that file was exported from exactly this
    checkpoint (the SHA-256 in its metadata); a stale or missing one falls back to torch under ``auto``.

    Raises:
        ConfigError: Unknown runtime, a missing file, ``torch`` asked for an ``.onnx`` file, or a checkpoint
            without a current ONNX file on a machine without torch (naming the command that converts it).
    """
    if runtime not in RUNTIMES:
        raise ConfigError(f"{who}: runtime must be one of {', '.join(RUNTIMES)}, got {runtime!r}")
    if not path.is_file():
        raise ConfigError(f"{who}: checkpoint {str(path)!r} does not exist")
    if path.suffix == ".onnx":
        if runtime == "torch":
            raise ConfigError(f"{who}: runtime=torch needs a .pt checkpoint, got the ONNX file {str(path)!r}")
        return "onnx", path
    if runtime == "torch":
        return "torch", path
    onnx = onnx_path_for(path)
    if onnx.is_file():
        if OnnxNet.source_of(onnx) == file_sha256(path):
            return "onnx", onnx
    why = (f"{onnx.name} beside it was exported from another checkpoint" if onnx.is_file()
           else f"it has no {onnx.name} beside it")
    if runtime == "onnx":
        raise ConfigError(f"{who}: runtime=onnx but {why}; convert it with: simtest export {path}")
    try:
        import torch  # noqa: F401
    except ImportError:
        raise ConfigError(f"{who}: checkpoint {str(path)!r} needs PyTorch to run, as {why}; convert it once "
                          f"with `simtest export {path}` (needs simtest[train]) or install torch") from None
    return "torch", path
