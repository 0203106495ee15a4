"""The path tracer's variant: libLLVM found and its version read without loading it, LLVM < 16 refused, the
fallback of ``auto`` logged once, an explicit ``llvm`` that cannot run an error, llvm_ad_rgb's bytes repeat
across runs and worker counts, and its ground truth is the fast profile's.

What depends on ``DRJIT_LIBLLVM_PATH`` runs in a subprocess: Dr.Jit reads it once, at ``import drjit``."""

from __future__ import annotations

import hashlib
import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from simtest.render.llvm import ENV, MIN_MAJOR, find_libllvm, llvm_major
from simtest.render.pbr import auto_spp

LIBLLVM = find_libllvm({})  # the newest >= 16 in the library folders, DRJIT_LIBLLVM_PATH left aside
OLD_LLVM = [p for p in ("/usr/lib/x86_64-linux-gnu/libLLVM-15.so.1", "/usr/lib/aarch64-linux-gnu/libLLVM-15.so.1",
                        "/usr/lib/x86_64-linux-gnu/libLLVM-14.so.1") if os.path.exists(p)]
needs_pbr = pytest.mark.skipif(any(importlib.util.find_spec(m) is None for m in ("mitsuba", "pyoidn")),
                               reason="mitsuba / pyoidn not installed (pip install 'simtest[pbr]')")
needs_llvm = pytest.mark.skipif(not LIBLLVM.usable, reason=f"no libLLVM >= {MIN_MAJOR}: {LIBLLVM.how} (e.g. "
                                                           f"apt-get install libllvm19)")
needs_old_llvm = pytest.mark.skipif(not OLD_LLVM, reason="no libLLVM 14 / 15 installed to be refused")
W, H = 48, 36


def _generate(out: Path, variant: str, env_path: str | None, workers: int = 1, scenes: int = 2,
              profile: str = "pbr", timeout: float = 300.0) -> subprocess.CompletedProcess:
    """``simtest generate`` (pbr, 2 spp, tiny images) in a fresh process with ``DRJIT_LIBLLVM_PATH`` set to
    ``env_path`` (``None``: unset)."""
    config = out.parent / f"{out.name}.toml"
    config.write_text(f'[render]\nprofile = "{profile}"\npbr_spp = 2\npbr_variant = "{variant}"\n')
    env = {k: v for k, v in os.environ.items() if k not in (ENV, "SIMTEST_PBR_VARIANT_NOTED")}
    if env_path is not None:
        env[ENV] = env_path
    args = ["generate", "--config", str(config), "--scenes", str(scenes), "--frames-per-scene", "2", "--width",
            str(W), "--height", str(H), "--objects", "builtin-small", "--seed", "5", "--workers", str(workers),
            "--out", str(out)]
    code = f"import sys; from simtest.cli import main; sys.exit(main({args!r}))"
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=timeout, env=env)


def _digest(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha1(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file() and p.name != "manifest.json"}


def _versions(root: Path) -> dict:
    return json.loads((root / "manifest.json").read_text())["versions"]


# --- finding libLLVM --------------------------------------------------------------------------------------
@needs_llvm
def test_found_library_is_the_newest_usable_and_its_version_comes_from_the_soname():
    major, how = llvm_major(str(LIBLLVM.path))
    assert major == LIBLLVM.major >= MIN_MAJOR and how.startswith("soname libLLVM")
    assert os.path.isfile(str(LIBLLVM.path))


@pytest.mark.skipif(not os.path.exists("/usr/lib/llvm-14/lib/libLLVM.so"), reason="no /usr/lib/llvm-14")
def test_version_of_an_unversioned_file_name_is_read_from_the_elf_file():
    assert llvm_major("/usr/lib/llvm-14/lib/libLLVM.so") == (14, "soname libLLVM-14.so.1")


def test_version_falls_back_to_the_file_name_and_then_gives_up(tmp_path):
    (tmp_path / "libLLVM-17.so").write_bytes(b"not an ELF file")
    (tmp_path / "libLLVM.so").write_bytes(b"not an ELF file")
    assert llvm_major(str(tmp_path / "libLLVM-17.so")) == (17, "file name libLLVM-17.so")
    major, how = llvm_major(str(tmp_path / "libLLVM.so"))
    assert major is None and "no LLVM version" in how
    lib = find_libllvm({}, dirs=(str(tmp_path),))
    assert lib.usable and lib.major == 17 and lib.path == str(tmp_path / "libLLVM-17.so")


def test_missing_or_unusable_env_path_is_refused_with_the_reason(tmp_path):
    missing = find_libllvm({ENV: str(tmp_path / "libLLVM-19.so")})
    assert not missing.usable and "does not exist" in missing.how
    folder = find_libllvm({ENV: str(tmp_path)})
    assert not folder.usable and "is a folder" in folder.how
    nothing = find_libllvm({}, dirs=(str(tmp_path),))
    assert not nothing.usable and nothing.major is None and "found: none" in nothing.how


@needs_old_llvm
def test_old_library_is_refused_by_path_and_by_search():
    lib = find_libllvm({ENV: OLD_LLVM[0]})
    assert not lib.usable and lib.major < MIN_MAJOR and f"needs LLVM >= {MIN_MAJOR}" in lib.how
    old_only = find_libllvm({}, dirs=("/usr/lib/llvm-1[0-5]/lib",))
    assert not old_only.usable


def test_auto_spp_follows_the_measured_knees():
    assert [auto_spp(w, h) for w, h in ((48, 36), (320, 240), (424, 240), (640, 480), (1280, 960))] == \
        [12, 12, 10, 6, 6]


# --- variant choice, in fresh processes -------------------------------------------------------------------
@needs_pbr
@pytest.mark.parametrize("where", ["empty folder", "missing file"])
def test_auto_falls_back_to_scalar_once_without_libllvm(tmp_path, where):
    empty = tmp_path / "nolib"
    empty.mkdir()
    env_path = str(empty) if where == "empty folder" else str(empty / "libLLVM.so.19.1")
    out = _generate(tmp_path / "ds", "auto", env_path, workers=2)
    assert out.returncode == 0, out.stderr
    assert out.stderr.count("path tracing on Mitsuba's scalar_rgb variant") == 1, out.stderr
    assert "apt-get install libllvm19" in out.stderr and env_path in out.stderr
    assert _versions(tmp_path / "ds")["mitsuba_variant"] == "scalar_rgb"
    assert "libllvm" not in _versions(tmp_path / "ds")


@needs_pbr
def test_explicit_llvm_without_libllvm_is_an_error_before_writing(tmp_path):
    out = _generate(tmp_path / "ds", "llvm", str(tmp_path / "missing.so"))
    assert out.returncode == 2, out.stderr
    assert "render.pbr_variant = 'llvm' cannot run" in out.stderr and "does not exist" in out.stderr
    assert "apt-get install libllvm19" in out.stderr and ENV in out.stderr
    assert not (tmp_path / "ds").exists()


@needs_pbr
@needs_old_llvm
def test_too_old_libllvm_is_refused_without_a_crash(tmp_path):
    explicit = _generate(tmp_path / "llvm", "llvm", OLD_LLVM[0])
    assert explicit.returncode == 2, explicit.stderr
    assert f"Mitsuba's LLVM variant needs LLVM >= {MIN_MAJOR}" in explicit.stderr and OLD_LLVM[0] in explicit.stderr
    auto = _generate(tmp_path / "auto", "auto", OLD_LLVM[0], scenes=1)
    assert auto.returncode == 0, auto.stderr
    assert _versions(tmp_path / "auto")["mitsuba_variant"] == "scalar_rgb"


@needs_pbr
@needs_llvm
def test_llvm_same_bytes_across_runs_and_worker_counts_and_the_fast_ground_truth(tmp_path):
    one = _generate(tmp_path / "w1", "llvm", None, workers=1)
    two = _generate(tmp_path / "w2", "auto", None, workers=2)  # auto: the same llvm_ad_rgb
    assert one.returncode == 0 and two.returncode == 0, one.stderr + two.stderr
    for run in ("w1", "w2"):
        v = _versions(tmp_path / run)
        assert v["mitsuba_variant"] == "llvm_ad_rgb" and v["libllvm"] == LIBLLVM.path
        assert v["libllvm_version"].split(".")[0] == str(LIBLLVM.major)
    assert _digest(tmp_path / "w1") == _digest(tmp_path / "w2")
    assert _generate(tmp_path / "fast", "auto", None, profile="fast").returncode == 0
    fast, pbr = _digest(tmp_path / "fast"), _digest(tmp_path / "w1")
    assert fast.keys() == pbr.keys()
    assert {k: v for k, v in fast.items() if "/rgb/" not in k} == {k: v for k, v in pbr.items() if "/rgb/" not in k}


# --- one renderer, many views -----------------------------------------------------------------------------
def _views_rendered(variant: str, fresh: bool, threads: int | None = None, views: int = 3,
                    freeze: bool = True, spp: int = 2) -> list[str]:
    from simtest.camera import CameraModel
    from simtest.generators.config import GenerateConfig
    from simtest.generators.pipeline import load_objects, prepare_scene
    from simtest.generators.recorder import scene_cameras
    from simtest.render.pbr import PbrRenderer

    cfg = GenerateConfig().replace(**{"objects": "builtin-small", "scenes": 1, "frames_per_scene": views,
                                      "camera.width": W, "camera.height": H, "scene.objects_per_scene": [3, 3],
                                      "seed": 3})
    scene, *_ = prepare_scene(cfg, load_objects(cfg), 0)
    camera = CameraModel(cfg.camera.K(), W, H)
    renderer = PbrRenderer(scene.model, camera, spp=spp, variant=variant, threads=threads)
    renderer.freeze = freeze
    out = []
    for im_id, (cam, _) in enumerate(scene_cameras(cfg, scene)):
        scene.set_camera(cam)
        if fresh:
            renderer = PbrRenderer(scene.model, camera, spp=spp, variant=variant, threads=threads)
            renderer.freeze = freeze
        rgb = renderer.render(scene.data, scene.camera_id, seed=11 + im_id).rgb
        out.append(hashlib.sha1(rgb.tobytes()).hexdigest())
    return out


@needs_pbr
def test_views_of_one_scene_reuse_the_loaded_scene_with_the_same_bytes():
    reused = _views_rendered("scalar", fresh=False)
    assert reused == _views_rendered("scalar", fresh=True) and len(set(reused)) == 3


_FROZEN_CHECK = """
import simtest.render.pbr as pbr  # before mitsuba: the LLVM variant can be chosen in this process
from simtest.errors import RenderError
try:
    pbr.resolved_variant("llvm")
except RenderError as exc:
    print("SKIP", exc)
    raise SystemExit(0)
from tests.simtest.render.test_pbr_variant import _views_rendered
reused = _views_rendered("llvm", fresh=False, views=5, spp=8)  # 8 samples, 4-sample guides
fresh = _views_rendered("llvm", fresh=True, views=5, spp=8)
traced = _views_rendered("llvm", fresh=False, views=5, freeze=False, spp=8)
print("DISTINCT", len(set(reused)), "FRESH", reused == fresh, "TRACED", reused == traced)
"""


def _in_fresh_process(code: str, *args: str) -> subprocess.CompletedProcess:
    """Run ``code`` in a new Python process from the repository root (where simtest picks libLLVM before Dr.Jit
    is imported); skips the test when the script prints ``SKIP`` (no LLVM variant here)."""
    root = Path(__file__).resolve().parents[3]
    res = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=600,
                         cwd=root, env={**os.environ, "PYTHONPATH": str(root)})
    if res.stdout.startswith("SKIP"):
        pytest.skip(res.stdout.strip())
    return res


@needs_pbr
def test_frozen_replays_give_the_bytes_of_renderers_made_anew():
    """On the LLVM variant the views of a loaded scene replay the kernels recorded at its first view (Dr.Jit
    frozen functions): five views give the bytes of a renderer made anew for each view (which records) and of
    one with freezing off. In a fresh process, where simtest picks libLLVM before Dr.Jit is imported."""
    res = _in_fresh_process(_FROZEN_CHECK)
    assert res.returncode == 0, res.stderr[-2000:]
    assert "DISTINCT 5 FRESH True TRACED True" in res.stdout, res.stdout + res.stderr[-2000:]


@needs_pbr
def test_thread_count_follows_the_renderer_argument():
    import drjit

    _views_rendered("scalar", fresh=False, threads=1)
    assert drjit.thread_count() == 1
    _views_rendered("scalar", fresh=False, threads=2)
    assert drjit.thread_count() == 2


def test_a_process_that_imported_drjit_first_pins_its_variant_for_the_workers(tmp_path):
    """Dr.Jit imported before simtest could point it at a libLLVM: ``auto`` resolves to scalar in that process;
    the spawned workers, which would find the LLVM variant, are told to use the same one, so 1 and 2 workers
    give the same bytes."""
    config = tmp_path / "pbr.toml"
    config.write_text('[render]\nprofile = "pbr"\npbr_spp = 2\n')
    digests = []
    for workers in (1, 2):
        out = tmp_path / f"w{workers}"
        args = ["generate", "--quiet", "--config", str(config), "--scenes", "2", "--frames-per-scene", "1", "--width",
                str(W), "--height", str(H), "--objects", "builtin-small", "--seed", "5", "--workers", str(workers),
                "--out", str(out)]
        code = f"import sys, drjit; from simtest.cli import main; sys.exit(main({args!r}))"
        env = {k: v for k, v in os.environ.items() if k not in (ENV, "SIMTEST_PBR_VARIANT_NOTED")}
        proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=env)
        assert proc.returncode == 0, proc.stderr
        digests.append({k: v for k, v in _digest(out).items() if "/rgb/" in k})
    assert digests[0] and digests[0] == digests[1]


_GC_DURING_RECORDING = """
import gc, sys
import simtest.render.pbr as pbr  # before mitsuba: the LLVM variant can be chosen in this process
from simtest.errors import RenderError
try:
    pbr.resolved_variant("llvm")
except RenderError as exc:
    print("SKIP", exc)
    raise SystemExit(0)
mi, _, _ = pbr._modules("llvm")
import drjit
import numpy as np
from simtest.render.pbr_shapes import mesh_from_arrays

class Node:
    pass

def body(x):
    for _ in range(5000):  # reference cycles: the collector runs while this records, unless paused
        a, b = Node(), Node()
        a.b, b.a = b, a
    return x + 1

frozen = drjit.freeze(body, auto_opaque=False)
x = mi.Float(np.ones(8, np.float32)) + 0
gc.collect()
gc.disable()
a, b = Node(), Node()  # an earlier scene's mesh (buffers from numpy) left in a reference cycle
a.mesh = mesh_from_arrays(mi, "old", np.random.default_rng(0).random((30, 3)), np.arange(30).reshape(10, 3))
a.b, b.a = b, a
del a, b
gc.enable()
from simtest.render.llvm import without_gc
y = without_gc(frozen, x) if sys.argv[1] == "guarded" else frozen(x)
print("OK", int(y[0]))
"""


@needs_pbr
def test_a_recording_is_not_broken_by_the_garbage_collector():
    """A collection that frees an earlier scene's numpy-backed mesh while Dr.Jit records a frozen function
    terminates the process ("RecordThreadState::enqueue_host_func(): this function cannot be recorded!", met
    once in 24 pbr scenes of a dataset); frozen renders run with the collector paused (``without_gc``)."""
    guarded = _in_fresh_process(_GC_DURING_RECORDING, "guarded")
    assert guarded.returncode == 0 and "OK 2" in guarded.stdout, guarded.stderr[-2000:]
    direct = _in_fresh_process(_GC_DURING_RECORDING, "direct")  # without the pause: the trigger is real here
    if direct.returncode == 0:
        pytest.skip("this Dr.Jit no longer aborts when a recording frees numpy-backed memory; the pause is harmless")
    assert "cannot be recorded" in direct.stderr, direct.stderr[-2000:]
