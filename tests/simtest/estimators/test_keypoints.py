"""The keypoint estimator: loss, fusion + PnP exactness, checkpoints, object-set checks, estimator plumbing."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from simtest.data import PoseDataset, collate  # noqa: E402
from simtest.errors import ConfigError  # noqa: E402
from simtest.estimators import load_estimator  # noqa: E402
from simtest.estimators.base import Observation  # noqa: E402
from simtest.estimators.keypoints import check_objects, fuse_keypoints, load_checkpoint, object_record, solve_pnp  # noqa: E402
from simtest.estimators.keypoints.infer import KeypointEstimator  # noqa: E402
from simtest.estimators.keypoints.loss import confidence, keypoint_loss, make_targets, total_loss  # noqa: E402
from simtest.estimators.keypoints.model import cell_centers  # noqa: E402
from simtest.training.keypoints import TrainConfig, build_model, train_keypoints  # noqa: E402
from simtest.evaluation.run import evaluate, load_dataset_objects  # noqa: E402


def _pad16(x):
    H, W = x.shape[-2:]
    return torch.nn.functional.pad(x, (0, (-W) % 16, 0, (-H) % 16))


def test_confidence_mapping_and_loss_optimum():
    z = torch.linspace(-5, 5, 11)
    x = torch.sigmoid(z)
    assert torch.allclose(confidence(z), torch.log(1 / (1 - x)), atol=1e-5)
    # per keypoint, c |g - e| - log c is smallest at c = 1 / |g - e|_1
    from simtest.estimators.keypoints.loss import Targets

    err = 0.25
    offsets = torch.zeros(1, 1, 2, 1, 1)
    tgt = Targets(cls=torch.ones(1, 1, 1, dtype=torch.int64), inst=torch.zeros(1, 1, 1, dtype=torch.int64),
                  offsets=torch.tensor([err, 0.0]).view(1, 1, 2, 1, 1))
    zs = torch.linspace(-3, 6, 2001)
    losses = torch.stack([keypoint_loss(offsets, zz.view(1, 1, 1, 1), tgt) for zz in zs])
    c_best = float(confidence(zs[losses.argmin()]))
    assert abs(c_best - 1 / err) < 0.05


def test_loss_decreases_on_tiny_dataset(small_dataset):
    ds = PoseDataset(small_dataset, crop=(64, 64))
    batch = collate([ds[i] for i in range(4)])
    net = build_model(ds.num_classes, 8, seed=0, widths=(8, 16, 16, 16), decoder=(16, 16))
    opt = torch.optim.Adam(net.parameters(), lr=3e-3)
    x = batch["rgb"]
    losses = []
    for _ in range(10):
        out = net(x)
        tg = make_targets(batch, tuple(out["seg"].shape[-2:]), 4, 32.0)
        loss = total_loss(out, tg)["loss"]
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
    assert losses[-1] < 0.8 * losses[0], losses


def test_model_is_deterministic_in_seed():
    a = build_model(4, 8, seed=3, widths=(8, 16, 16, 16), decoder=(16, 16))
    b = build_model(4, 8, seed=3, widths=(8, 16, 16, 16), decoder=(16, 16))
    c = build_model(4, 8, seed=4, widths=(8, 16, 16, 16), decoder=(16, 16))
    sa, sb, sc = a.state_dict(), b.state_dict(), c.state_dict()
    assert all(torch.equal(sa[k], sb[k]) for k in sa)
    assert any(not torch.equal(sa[k], sc[k]) for k in sa)
    out = a(torch.zeros(1, 3, 64, 96))
    assert out["seg"].shape == (1, 5, 16, 24)
    assert out["offsets"].shape == (1, 8, 2, 16, 24) and out["conf_logit"].shape == (1, 8, 16, 24)


def test_fusion_and_pnp_recover_gt_pose_from_exact_offsets(small_dataset):
    ds = PoseDataset(small_dataset)
    checked = 0
    for i in range(len(ds)):
        b = collate([ds[i]])
        H, W = _pad16(b["rgb"]).shape[-2:]
        tg = make_targets(b, (H // 4, W // 4), 4, 32.0)
        pts = (tg.offsets[0].double() * 32.0 + cell_centers(H // 4, W // 4, 4, dtype=torch.float64)[None])
        for k in range(len(b["obj_ids"])):
            cells = (tg.inst[0] == k).numpy()
            if cells.sum() < 2:
                continue
            P = pts[:, :, cells].permute(2, 0, 1).numpy()
            conf = np.random.default_rng(k).uniform(0.5, 2.0, size=P.shape[:2])
            kp, kc = fuse_keypoints(P, conf, top_n=5)
            # fusion of exact predictions is exact (up to the float32 offset maps)
            assert np.abs(kp - b["keypoints_2d"][k].numpy()).max() < 1e-4
            R, t, rms = solve_pnp(kp, b["keypoints_3d"][k].numpy(), b["K"][0].numpy())
            assert np.abs(t - b["t_sym"][k].numpy()).max() < 1e-6  # metres
            dR = R.T @ b["R_sym"][k].numpy()
            angle = np.arccos(np.clip((np.trace(dR) - 1) / 2, -1, 1))
            assert angle < 1e-4  # radians
            # and exactly from float64 keypoints, with RANSAC too
            for method in ("ransac", "sqpnp"):
                R2, t2, _ = solve_pnp(b["keypoints_2d"][k].numpy(), b["keypoints_3d"][k].numpy(),
                                      b["K"][0].numpy(), method=method)
                assert np.abs(t2 - b["t_sym"][k].numpy()).max() < 1e-7
            checked += 1
    assert checked >= 5


def test_fuse_keypoints_weights_and_threshold():
    pts = np.array([[[0.0, 0.0]], [[10.0, 0.0]], [[100.0, 0.0]]])
    conf = np.array([[1.0], [3.0], [0.1]])
    kp, kc = fuse_keypoints(pts, conf, top_n=2)
    assert np.allclose(kp, [[7.5, 0.0]]) and np.allclose(kc, [2.0])
    kp, _ = fuse_keypoints(pts, conf, top_n=3, min_conf=2.0)
    assert np.allclose(kp, [[10.0, 0.0]])
    kp, _ = fuse_keypoints(pts, conf, top_n=3, min_conf=50.0)  # none above: the best one
    assert np.allclose(kp, [[10.0, 0.0]])
    with pytest.raises(ConfigError, match="shape"):
        fuse_keypoints(np.zeros((0, 8, 2)), np.zeros((0, 8)))
    with pytest.raises(ConfigError, match="'dlt'.*epnp, sqpnp, ransac"):
        solve_pnp(np.zeros((8, 2)), np.zeros((8, 3)), np.eye(3), method="dlt")


@pytest.fixture(scope="module")
def trained_run(small_dataset, tmp_path_factory):
    out = tmp_path_factory.mktemp("kp") / "run"
    cfg = TrainConfig(data=str(small_dataset), out=str(out), val=str(small_dataset), epochs=2, batch_size=3,
                      crop=(64, 64), workers=0, widths=(8, 16, 16, 16), decoder=(16, 16), seed=1)
    res = train_keypoints(cfg, progress=False, log=lambda s: None)
    return cfg, res


def test_checkpoint_round_trip_and_resume(trained_run, small_dataset):
    cfg, res = trained_run
    for path in (res.model_path, res.last_path, res.best_path):
        ck = torch.load(path, weights_only=True)
        assert ck["objects"]["obj_ids"] == sorted(o.obj_id for o in load_dataset_objects(small_dataset))
        assert ck["objects"]["names"] and len(ck["objects"]["mesh_hashes"][0]) == 40
        assert np.asarray(ck["objects"]["keypoints"]).shape[1:] == (8, 3)
        assert ck["train"]["seed"] == 1 and ck["net"]["num_keypoints"] == 8
    assert len(res.history) == 2 and "val_add_s_or_add_01d" in res.history[0]
    ck = load_checkpoint(res.model_path)
    est = KeypointEstimator(checkpoint=res.model_path, runtime="torch")
    sd = est.model.state_dict()
    assert all(torch.equal(sd[k], ck["model"][k]) for k in ck["model"])
    # resuming a finished run for more epochs continues from the saved state
    cfg3 = TrainConfig(**{**cfg.__dict__, "epochs": 3})
    res3 = train_keypoints(cfg3, resume=True, progress=False, log=lambda s: None)
    assert [h["epoch"] for h in res3.history] == [0, 1, 2]
    assert res3.history[:2] == res.history
    with pytest.raises(ConfigError, match="already holds a run"):
        train_keypoints(cfg3, resume=False, progress=False, log=lambda s: None)


def test_warm_start_loads_the_weights_and_refuses_another_network(trained_run, tmp_path):
    cfg, res = trained_run
    ck = load_checkpoint(res.model_path)
    # a learning rate of 1e-12 keeps the weights where they started: they must be the init checkpoint's
    init = tmp_path / "init.pt"
    init.write_bytes(res.model_path.read_bytes())
    warm = TrainConfig(**{**cfg.__dict__, "out": str(tmp_path / "warm"), "epochs": 1, "lr": 1e-12, "seed": 7,
                          "init": str(init)})
    res_w = train_keypoints(warm, progress=False, log=lambda s: None)
    ck_w = torch.load(res_w.model_path, weights_only=True)
    # batch-norm statistics move in training mode whatever the learning rate; the parameters must not
    params = {k for k in ck["model"] if not k.endswith(("running_mean", "running_var", "num_batches_tracked"))}
    assert params and all(torch.allclose(ck_w["model"][k], ck["model"][k], atol=1e-9) for k in params)
    sha = hashlib.sha256(init.read_bytes()).hexdigest()
    assert ck_w["train"]["init_sha256"] == sha and ck_w["train"]["init"] == str(init)
    # resuming continues from last.pt: the init file is not read again, its hash stays recorded
    init.unlink()
    res_r = train_keypoints(TrainConfig(**{**warm.__dict__, "epochs": 2}), resume=True, progress=False,
                            log=lambda s: None)
    assert [h["epoch"] for h in res_r.history] == [0, 1]
    assert torch.load(res_r.model_path, weights_only=True)["train"]["init_sha256"] == sha
    init.write_bytes(res.model_path.read_bytes())
    # a cold start with the same settings does not begin there
    cold = TrainConfig(**{**warm.__dict__, "out": str(tmp_path / "cold"), "init": None})
    ck_c = torch.load(train_keypoints(cold, progress=False, log=lambda s: None).model_path, weights_only=True)
    assert not all(torch.allclose(ck_c["model"][k], ck["model"][k], atol=1e-6) for k in params)
    assert "init_sha256" not in ck_c["train"]
    # another network configuration names the field
    with pytest.raises(ConfigError, match=r"another network: decoder \[16, 16\] there, \[16, 8\] here.*options it was trained"):
        train_keypoints(TrainConfig(**{**warm.__dict__, "out": str(tmp_path / "d"), "decoder": (16, 8)}),
                        progress=False, log=lambda s: None)
    # another object set (a changed mesh) and a missing file
    bad = dict(ck)
    bad["objects"] = {**ck["objects"], "mesh_hashes": ["0" * 40] + list(ck["objects"]["mesh_hashes"][1:]),
                      "bbox_corners": [np.add(ck["objects"]["bbox_corners"][0], 0.01).tolist()]
                      + list(ck["objects"]["bbox_corners"][1:])}
    torch.save(bad, tmp_path / "other_objects.pt")
    with pytest.raises(ConfigError, match="mesh differs"):
        train_keypoints(TrainConfig(**{**warm.__dict__, "out": str(tmp_path / "o"),
                                       "init": str(tmp_path / "other_objects.pt")}), progress=False, log=lambda s: None)
    with pytest.raises(ConfigError, match="does not exist"):
        train_keypoints(TrainConfig(**{**warm.__dict__, "out": str(tmp_path / "m"), "init": str(tmp_path / "no.pt")}),
                        progress=False, log=lambda s: None)


def test_estimator_by_name_runs_in_eval(trained_run, small_dataset, tmp_path):
    _, res = trained_run
    est = load_estimator("keypoints-full", checkpoint=str(res.model_path), top_n=4)
    assert isinstance(est, KeypointEstimator)
    rep = evaluate(small_dataset, est, vsd=False, progress=False, max_images=2)
    assert rep.overall["num_image_exceptions"] == 0
    assert 0.0 <= rep.overall["add_s_or_add_01d"] <= 1.0
    # segmentation mode (no targets) runs too
    rep2 = evaluate(small_dataset, est, targets="none", vsd=False, progress=False, max_images=2)
    assert rep2.overall["num_image_exceptions"] == 0


def test_mismatched_object_set_is_a_clear_error(trained_run, small_dataset):
    from simtest.objects import load_object_set

    _, res = trained_run
    est = KeypointEstimator(checkpoint=res.model_path)
    other = load_object_set("builtin").subset([2, 3, 4])
    obs = Observation(rgb=np.zeros((120, 160, 3), np.uint8), depth=np.zeros((120, 160), np.float32),
                      K=np.eye(3), width=160, height=120, objects=other)
    with pytest.raises(ConfigError) as err:
        est.estimate(obs)
    msg = str(err.value)
    assert "trained for objects [1 can_0" in msg and "2 " in msg and "object ids differ" in msg
    # same ids, different meshes
    ck = load_checkpoint(res.model_path)
    rec = dict(ck["objects"])
    rec["mesh_hashes"] = ["0" * 40] + rec["mesh_hashes"][1:]
    rec["bbox_corners"] = [np.add(rec["bbox_corners"][0], 0.01).tolist()] + rec["bbox_corners"][1:]
    with pytest.raises(ConfigError, match="object 1 mesh differs"):
        check_objects(rec, load_dataset_objects(small_dataset))
    # the dataset's own objects pass, also after a float32 file round trip of the meshes
    check_objects(ck["objects"], load_dataset_objects(small_dataset))
    assert object_record(load_dataset_objects(small_dataset))["obj_ids"] == ck["objects"]["obj_ids"]


def test_bad_checkpoint_paths(tmp_path):
    with pytest.raises(ConfigError, match="does not exist"):
        KeypointEstimator(checkpoint=tmp_path / "missing.pt")
    torch.save({"hello": torch.zeros(1)}, tmp_path / "other.pt")
    with pytest.raises(ConfigError, match="not a keypoint-estimator checkpoint"):
        KeypointEstimator(checkpoint=tmp_path / "other.pt")
    with pytest.raises(ConfigError, match="checkpoint=PATH"):
        KeypointEstimator()
