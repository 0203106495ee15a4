"""Mask and depth PNGs written by simtest.io.png decode to their arrays with OpenCV and Pillow, as OpenCV's own
encoder's do."""

from __future__ import annotations

import io

import cv2
import numpy as np
import pytest
from PIL import Image

from simtest.io.bop import decode_depth, encode_depth, encode_image, read_depth, read_mask
from simtest.io.png import encode_depth_png, encode_mask_png


def _masks():
    rng = np.random.default_rng(0)
    yield np.zeros((48, 64), dtype=bool)  # empty
    yield np.ones((1, 1), dtype=bool)
    blob = np.zeros((480, 640), dtype=bool)
    yy, xx = np.mgrid[:480, :640]
    blob[(yy - 200) ** 2 + (xx - 300) ** 2 < 90 ** 2] = True
    yield blob
    yield rng.random((97, 131)) < 0.5  # noise: many short runs, long compressed rows
    yield (rng.random((30, 40)) < 0.3).astype(np.uint8) * 7  # any non-zero value is inside


@pytest.mark.parametrize("mask", list(_masks()), ids=["empty", "1x1", "disc", "noise", "uint8"])
def test_mask_png_decodes_to_the_mask_with_opencv_and_pillow(mask):
    data = encode_mask_png(mask)
    expected = np.where(mask != 0, 255, 0).astype(np.uint8)
    ours_cv = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    pil = Image.open(io.BytesIO(data))
    pil.verify()  # chunk CRCs and structure
    ours_pil = np.asarray(Image.open(io.BytesIO(data)))
    ok, ref = cv2.imencode(".png", expected)
    assert ok and np.array_equal(cv2.imdecode(ref, cv2.IMREAD_UNCHANGED), expected)
    assert ours_cv.dtype == np.uint8 and np.array_equal(ours_cv, expected)
    assert pil.mode == "L" and np.array_equal(ours_pil, expected)
    assert encode_image(expected, ".png", mask=True) == data


def test_mask_png_round_trips_through_the_bop_reader(tmp_path):
    mask = np.zeros((20, 30), dtype=bool)
    mask[5:12, 3:25] = True
    (tmp_path / "mask_visib").mkdir()
    (tmp_path / "mask_visib" / "000000_000000.png").write_bytes(encode_mask_png(mask))
    assert np.array_equal(read_mask(tmp_path, 0, 0, visible=True), mask)


@pytest.mark.parametrize("bad", [np.zeros((0, 4), bool), np.zeros((2, 2, 3), bool), np.zeros(5, bool)])
def test_mask_png_rejects_what_is_not_a_mask(bad):
    with pytest.raises(ValueError, match="non-empty \\(H, W\\)"):
        encode_mask_png(bad)


def _depths():
    rng = np.random.default_rng(1)
    yield np.zeros((48, 64), dtype=np.uint16)
    yield np.full((1, 1), 65535, dtype=np.uint16)
    yy, xx = np.mgrid[:480, :640]
    yield (4000 + 3 * yy + (xx % 7) * 300).astype(np.uint16)  # smooth ramps, steps across the byte boundary
    yield rng.integers(0, 65536, size=(97, 131), dtype=np.uint16)  # noise: every byte value, wrapping differences
    yield np.asfortranarray(rng.integers(0, 3000, size=(30, 41), dtype=np.uint16))  # any memory layout


@pytest.mark.parametrize("depth", list(_depths()), ids=["zeros", "1x1-max", "ramps", "noise", "fortran"])
def test_depth_png_decodes_to_the_depth_with_opencv_and_pillow(depth):
    data = encode_depth_png(depth)
    ours_cv = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    assert ours_cv.dtype == np.uint16 and np.array_equal(ours_cv, depth)
    pil = Image.open(io.BytesIO(data))
    pil.verify()
    assert np.array_equal(np.asarray(Image.open(io.BytesIO(data))).astype(np.uint16), depth)
    assert encode_image(depth, ".png") == data == encode_depth_png(depth.copy())  # one encoder, same bytes


def test_depth_png_round_trips_through_the_bop_reader(tmp_path):
    depth_m = np.linspace(0.0, 2.5, 24 * 32, dtype=np.float32).reshape(24, 32)
    (tmp_path / "depth").mkdir()
    (tmp_path / "depth" / "000000.png").write_bytes(encode_depth_png(encode_depth(depth_m, 0.1)))
    got = read_depth(tmp_path, 0, 0.1)
    assert np.array_equal(got, decode_depth(encode_depth(depth_m, 0.1), 0.1))
    assert np.abs(got - depth_m).max() <= 0.05e-3 + 1e-6  # half a quantisation step (0.1 mm)


@pytest.mark.parametrize("bad", [np.zeros((0, 4), np.uint16), np.zeros((2, 2, 3), np.uint16),
                                 np.zeros((3, 3), np.float32)])
def test_depth_png_rejects_what_is_not_a_depth_image(bad):
    with pytest.raises(ValueError, match="uint16"):
        encode_depth_png(bad)
