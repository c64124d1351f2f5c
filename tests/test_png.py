"""The PNG writer (fuse4d.io._png): lossless for every image fuse4d writes, read back by
OpenCV and Pillow."""

from __future__ import annotations

import io

import cv2
import numpy as np
import pytest
from PIL import Image

from fuse4d.io._images import encode_png
from fuse4d.io._png import png_bytes


def _cv2_decode(data: bytes) -> np.ndarray:
    return cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)


_RNG = np.random.default_rng(7)
_CASES = {
    "gray8": _RNG.integers(0, 256, (37, 53), dtype=np.uint8),
    "gray16": _RNG.integers(0, 65536, (37, 53), dtype=np.uint16),
    "bgr8": _RNG.integers(0, 256, (19, 23, 3), dtype=np.uint8),
    "bgra8": _RNG.integers(0, 256, (19, 23, 4), dtype=np.uint8),
    "bgr16": _RNG.integers(0, 65536, (19, 23, 3), dtype=np.uint16),
    "one_pixel": np.array([[65535]], np.uint16),
    "one_column": _RNG.integers(0, 256, (9, 1), dtype=np.uint8),
    "one_row": _RNG.integers(0, 65536, (1, 9), dtype=np.uint16),
    # every difference to the row above wraps around (0 <-> 255, 0 <-> 65535)
    "extremes16": np.tile(np.array([[0, 65535], [65535, 0]], np.uint16), (8, 8)),
    "strided": _RNG.integers(0, 65536, (40, 60), dtype=np.uint16)[::2, 1::3],
}


@pytest.mark.parametrize("name", list(_CASES))
def test_opencv_decodes_exactly_the_image(name):
    image = _CASES[name]
    np.testing.assert_array_equal(_cv2_decode(png_bytes(image)), image)


@pytest.mark.parametrize("name", ["gray8", "gray16", "bgr8", "bgra8", "strided"])
def test_pillow_decodes_the_same_pixels_in_rgb_order(name):
    image = _CASES[name]
    decoded = np.asarray(Image.open(io.BytesIO(png_bytes(image))))
    if image.ndim == 3:  # OpenCV's BGR(A) in, the PNG holds RGB(A)
        image = image[..., [2, 1, 0, 3][: image.shape[2]]]
    np.testing.assert_array_equal(decoded.astype(image.dtype), image)


def test_a_frame_sized_depth_is_smaller_than_its_samples():
    """A smooth 640 x 480 depth ramp with noise compresses (the IDAT is really deflated)."""
    v, u = np.mgrid[0:480, 0:640]
    depth = (1500 + 2 * u + v + _RNG.integers(0, 3, u.shape)).astype(np.uint16)
    data = png_bytes(depth)
    assert len(data) < depth.nbytes / 3
    np.testing.assert_array_equal(_cv2_decode(data), depth)


def test_encode_png_writes_the_file(tmp_path):
    image = _CASES["gray16"]
    path = tmp_path / "d.png"
    encode_png(image, path)
    np.testing.assert_array_equal(cv2.imread(str(path), cv2.IMREAD_UNCHANGED), image)


@pytest.mark.parametrize(
    ("image", "match"),
    [
        (np.zeros((4, 4), np.float32), "uint8 or uint16"),
        (np.zeros((4, 4), np.bool_), "uint8 or uint16"),
        (np.zeros((4, 4, 2), np.uint8), r"\(H, W\)"),
        (np.zeros(4, np.uint8), r"\(H, W\)"),
        (np.zeros((0, 4), np.uint8), "empty"),
    ],
)
def test_unsupported_images_are_refused(image, match):
    with pytest.raises(ValueError, match=match):
        png_bytes(image)
