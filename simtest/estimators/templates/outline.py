"""The outline stage of the template estimator: a found pose's silhouette, moved onto the object as the outline
network draws it (:mod:`.mask_model`, trained by ``simtest train outlines``: its visible pixels, or with
``--target amodal`` its whole silhouette, hidden parts too, as LM-O's shipped networks draw it, so that the fit
is not pulled back where something lies in front), and the pose's translation fitted to that mask.

:func:`outline_fit` looks at the pose through the crop the templates use (the pose's own silhouette framed with
margin 1.2), asks the network for the visible mask with the silhouette as its prior, and moves the object
along its viewing ray and across the image (depth by at most ``max_scale``) until its silhouette agrees with
that mask best (:func:`simtest.estimators.silhouette.fit_translation`); small turns follow (``step_deg``). The mask
is read one of three ways (``mask_mode``, :data:`MASK_MODES`): ``"hard"`` the pixels whose logit is positive;
``"soft"`` the network's probability, so that pixels it is unsure of weigh less in the fit's IoU; ``"soft+flip"``
the mean probability of the crop and of its mirror image (the network run twice). A ``temperature`` T > 1
divides the logits before the sigmoid, so the probability is flatter: the fit's soft IoU takes in a pixel when
its probability exceeds about ``IoU / (1 + IoU)`` (0.44 at IoU 0.8), so a flatter probability lets the silhouette
grow over pixels the network leans against, i.e. pulls the pose nearer. On the real LM-O frames the poses fitted
to the eighth round's visible-pixel network lay a median 0.2 % too far at T = 1, 0.1 % too near at T = 2 and 1.6 %
too near at T = 4 (docs/sim2real.md, eleventh round). ``"hard"`` is the same at any temperature. Several
networks (``A.onnx+B.onnx``, :func:`load_outline`; every shipped one of a set, :func:`shipped_outline`) are read
as one: their probabilities averaged. Inference runs through ONNX Runtime (no torch) from the ``.onnx`` file
beside a checkpoint, or through torch from a ``.pt``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from simtest.errors import ConfigError
from simtest.estimators.onnx_net import OnnxNet, resolve_runtime
from simtest.estimators.templates.crops import mask_in_crop, region_crop
from simtest.render.silhouette import object_silhouette

__all__ = ["FORMAT", "FAMILY", "OutlineNet", "OutlineNets", "load_outline", "OutlineFit", "outline_fit", "fit_to_mask",
           "shipped_outline", "MARGIN",
           "MIN_SILHOUETTE_PX", "MASK_MODES", "check_mask_mode", "check_temperature"]

#: The ``format`` entry of outline-network checkpoints and ONNX files.
FORMAT = "simtest-outline/1"
#: Margin of the crop around the pose's silhouette (as the templates are cropped).
MARGIN = 1.2
#: A pose whose silhouette covers fewer image pixels is left as it is.
MIN_SILHOUETTE_PX = 50
#: How :func:`outline_fit` reads the network's output (see the module doc).
MASK_MODES = ("hard", "soft", "soft+flip")


class OutlineNet:
    """An outline network from its checkpoint (``.pt``) or ONNX file.

    Args:
        path: ``model.onnx`` / ``model.pt`` of ``simtest train outlines`` (or a shipped file).
        runtime: ``auto``, ``onnx`` or ``torch`` (:func:`simtest.estimators.onnx_net.resolve_runtime`).
        threads: ONNX Runtime threads (None: 1).

    Raises:
        ConfigError: A missing or unreadable file, or one of another format.
    """

    def __init__(self, path: str | Path, runtime: str = "auto", threads: int | None = None) -> None:
        self.runtime, p = resolve_runtime(Path(path), runtime, "templates (outline network)")
        self.path = str(p)
        if self.runtime == "onnx":
            self.net = OnnxNet(p, FORMAT, threads)
            self.record, cfg = self.net.meta["objects"], self.net.meta["net"]
        else:
            import torch

            from simtest.estimators.checkpoint import load_checkpoint
            from simtest.estimators.templates.mask_model import MaskNet, MaskNetConfig

            ckpt = load_checkpoint(p, fmt=FORMAT)
            self.model = MaskNet(MaskNetConfig.from_dict(ckpt["net"]))
            self.model.load_state_dict(ckpt["model"])
            self.model.eval()
            self.record, cfg = ckpt["objects"], ckpt["net"]
            self._torch = torch
        self.size = int(cfg["crop_size"])

    def logits(self, crop_rgb: np.ndarray, prior: np.ndarray) -> np.ndarray:
        """The mask logits (S, S) float32 of a crop (S, S, 3) uint8 given the prior silhouette (S, S) bool."""
        S = self.size
        if crop_rgb.shape != (S, S, 3) or prior.shape != (S, S):
            raise ConfigError(f"outline network: needs a ({S}, {S}, 3) crop and a ({S}, {S}) prior, got "
                              f"{crop_rgb.shape} and {prior.shape}")
        x = np.concatenate([crop_rgb.transpose(2, 0, 1).astype(np.float32) / np.float32(255.0),
                            np.asarray(prior, np.float32)[None]], 0)[None]
        if self.runtime == "onnx":
            logits = self.net.run(x)[0]
        else:
            with self._torch.inference_mode():
                logits = self.model(self._torch.from_numpy(x)).numpy()
        return logits[0, 0]

    def mask(self, crop_rgb: np.ndarray, prior: np.ndarray) -> np.ndarray:
        """The visible mask (S, S) bool of a crop (S, S, 3) uint8 given the prior silhouette (S, S) bool."""
        return self.logits(crop_rgb, prior) > 0

    def probability(self, crop_rgb: np.ndarray, prior: np.ndarray, flip: bool = False,
                    temperature: float = 1.0) -> np.ndarray:
        """The probability (S, S) float64 in [0, 1] that each pixel of the crop is one of the object's visible
        pixels, ``sigmoid(logit / temperature)``; with ``flip`` the mean of the crop's and of its mirror image's
        (mirrored back)."""
        T = check_temperature(temperature)
        p = _sigmoid(self.logits(crop_rgb, prior) / T)
        if flip:
            mirrored = self.logits(np.ascontiguousarray(crop_rgb[:, ::-1]), np.ascontiguousarray(prior[:, ::-1]))
            p = 0.5 * (p + _sigmoid(mirrored / T)[:, ::-1])
        return p

    def read(self, crop_rgb: np.ndarray, prior: np.ndarray, mode: str = "hard", temperature: float = 1.0) -> np.ndarray:
        """The mask the fit uses, read as ``mode`` says (:data:`MASK_MODES`): bool for ``"hard"``, else the
        probability (float64) at ``temperature``.

        Raises:
            ConfigError: An unknown ``mode``, naming the allowed ones, or a temperature that is not a positive
                finite number.
        """
        T = check_temperature(temperature)
        if check_mask_mode(mode, "outline network: mask mode") == "hard":
            return self.mask(crop_rgb, prior)
        return self.probability(crop_rgb, prior, flip=mode == "soft+flip", temperature=T)


class OutlineNets:
    """Several outline networks read as one: their probabilities averaged (each read as :meth:`OutlineNet.read`
    reads it, at the same temperature), ``"hard"`` the pixels where that mean exceeds 0.5.

    Args:
        nets: The networks, all with the same crop size.

    Raises:
        ConfigError: No network, or networks with different crop sizes (naming the files and sizes).
    """

    def __init__(self, nets: list[OutlineNet]) -> None:
        if not nets:
            raise ConfigError("outline networks: need at least one network")
        sizes = {n.size for n in nets}
        if len(sizes) != 1:
            raise ConfigError("outline networks: all must take the same crop size, got "
                              + ", ".join(f"{n.path}: {n.size}" for n in nets))
        self.nets, self.size = list(nets), nets[0].size
        self.path = "+".join(n.path for n in nets)

    def read(self, crop_rgb: np.ndarray, prior: np.ndarray, mode: str = "hard", temperature: float = 1.0) -> np.ndarray:
        """The mean of the networks' probabilities (``mode`` ``soft`` or ``soft+flip``) or its pixels above 0.5
        (``hard``), as :meth:`OutlineNet.read`."""
        hard = check_mask_mode(mode, "outline network: mask mode") == "hard"
        p = np.mean([n.read(crop_rgb, prior, "soft" if hard else mode, temperature) for n in self.nets], axis=0)
        return p > 0.5 if hard else p


def load_outline(spec: str | Path, runtime: str = "auto", threads: int | None = None) -> OutlineNet | OutlineNets:
    """The outline network of ``spec``: one file (``.onnx`` / ``.pt``), or several joined by ``+`` read as one
    (:class:`OutlineNets`)."""
    paths = [p for p in str(spec).split("+") if p]
    if len(paths) == 1:
        return OutlineNet(paths[0], runtime, threads)
    return OutlineNets([OutlineNet(p, runtime, threads) for p in paths])


def check_mask_mode(value: str, name: str = "outline fit: mask_mode") -> str:
    """``value`` when it is one of :data:`MASK_MODES`, or a ConfigError naming ``name``, the value and the modes."""
    if value not in MASK_MODES:
        raise ConfigError(f"{name} {value!r} is unknown; allowed: {', '.join(MASK_MODES)}")
    return value


def check_temperature(value: float, name: str = "outline network: temperature") -> float:
    """``value`` as a temperature (a positive finite float), or a ConfigError naming ``name`` and the value."""
    try:
        T = float(value)
    except (TypeError, ValueError):
        T = float("nan")
    if not (np.isfinite(T) and T > 0.0):
        raise ConfigError(f"{name} must be a positive number, got {value!r}")
    return T


def _sigmoid(z: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-np.asarray(z, np.float64)))


@dataclass
class OutlineFit:
    """What :func:`outline_fit` did: the pose (model to camera, metres), whether the fit moved it, the IoU of the
    silhouette with the network's mask before and after, and the depth ratio after / before."""

    R: np.ndarray
    t: np.ndarray
    applied: bool
    iou_before: float
    iou_after: float
    scale: float

    def info(self) -> dict[str, Any]:
        return {"applied": self.applied, "iou_before": self.iou_before, "iou_after": self.iou_after,
                "scale": self.scale}


def outline_fit(net: OutlineNet | OutlineNets, obj, rgb: np.ndarray, K: np.ndarray, R: np.ndarray, t: np.ndarray,
                max_scale: float = 0.1, step_deg: float = 2.0, mask_mode: str = "hard",
                temperature: float = 1.0) -> OutlineFit:
    """The pose ``(R, t)`` of ``obj`` in image ``rgb`` (H, W, 3) uint8 with intrinsics ``K`` refined by the
    outline network's mask (see the module doc); ``max_scale`` bounds the depth change ``|s - 1|``, ``step_deg``
    is the first rotation step (degrees; 0: the rotation stays), ``mask_mode`` how the network's output is read
    (:data:`MASK_MODES`) and ``temperature`` how flat its probability is (the soft modes).

    Raises:
        ConfigError: An unknown ``mask_mode`` or a temperature that is not a positive number.
    """
    check_mask_mode(mask_mode)
    T = check_temperature(temperature)
    return fit_to_mask(obj, rgb, K, R, t, lambda crop: net.read(crop.rgb, crop.mask, mask_mode, T), net.size,
                       max_scale, step_deg)


def fit_to_mask(obj, rgb: np.ndarray, K: np.ndarray, R: np.ndarray, t: np.ndarray,
                mask_of: Callable[[Any], np.ndarray], size: int, max_scale: float = 0.1,
                step_deg: float = 2.0, hidden: np.ndarray | None = None) -> OutlineFit:
    """:func:`outline_fit` with the mask drawn by ``mask_of(crop)`` ((size, size) bool, or a probability in
    [0, 1]) for the crop
    (:class:`~simtest.estimators.templates.crops.Crop`) framed on the pose's silhouette: the network's, or an
    exact visible mask warped into the crop (docs/sim2real_outline.py). ``hidden`` (H, W) bool: image pixels
    left out of the fit (e.g. where other objects lie in front; docs/sim2real_refit.py)."""
    from simtest.estimators.silhouette import fit_translation

    R, t, K = np.asarray(R, np.float64), np.asarray(t, np.float64).reshape(3), np.asarray(K, np.float64)
    H, W = rgb.shape[:2]
    sil = object_silhouette(obj, R, t, K, W, H) if t[2] > 0 else np.zeros((H, W), bool)
    if int(sil.sum()) < MIN_SILHOUETTE_PX:
        return OutlineFit(R, t, False, 0.0, 0.0, 1.0)
    crop = region_crop(rgb, sil, K, size, MARGIN)
    mask = mask_of(crop)
    Rv = crop.R_virt
    valid = crop.valid if hidden is None else crop.valid & ~(mask_in_crop(hidden, K, crop) > 0)
    fit = fit_translation(obj, Rv @ R, Rv @ t, crop.K, mask.astype(np.float64), valid, max_scale=max_scale,
                          step_deg=step_deg)
    if not fit.applied:  # the fit kept the pose: give it back as it came
        return OutlineFit(R, t, False, float(fit.iou_before), float(fit.iou_after), 1.0)
    R2, t2 = Rv.T @ fit.R, Rv.T @ fit.t
    return OutlineFit(R2, t2, True, float(fit.iou_before), float(fit.iou_after), float(t2[2] / t[2]))


#: The shipped outline networks' family (``weights/templates_outline_<set>_<W>x<H>.onnx``).
FAMILY = "templates_outline"


def shipped_outline(objects) -> str | None:
    """The ONNX files of the shipped outline networks trained for ``objects`` (compared by content: ids and
    meshes; the dataset may hold more objects), joined by ``+`` (read as one by :func:`load_outline`; a set's
    network without a variant first), or None when none was."""
    from simtest.estimators.shipped import matches, shipped_nets

    found = [str(net.path.with_suffix(".onnx")) for net in shipped_nets(FAMILY, FORMAT)
             if matches(net.record, objects, subset=True) is None]
    return "+".join(found) if found else None
