"""The PNG writer and gray reader (fuse4d.io._png): lossless for every image fuse4d writes,
read back by OpenCV and Pillow; the gray reader returns what OpenCV returns, or hands the file
to OpenCV."""

from __future__ import annotations

import io
import struct
import zlib

import cv2
import numpy as np
import pytest
from PIL import Image

from fuse4d.errors import InputFileError
from fuse4d.io._images import decode_image, encode_png
from fuse4d.io._png import _chunk, decode_gray_png, png_bytes


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


# ------------------------------------------------------------------------------ gray reader
_GRAY = ["gray8", "gray16", "one_pixel", "one_column", "one_row", "extremes16", "strided"]


@pytest.mark.parametrize("name", _GRAY)
def test_gray_reader_returns_what_opencv_returns_for_fuse4ds_pngs(name):
    data = png_bytes(_CASES[name])
    decoded = decode_gray_png(data)
    assert decoded is not None
    assert decoded.dtype == _cv2_decode(data).dtype
    assert decoded.flags.writeable
    assert decoded.dtype.isnative
    np.testing.assert_array_equal(decoded, _CASES[name])


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
@pytest.mark.parametrize("shape", [(37, 53), (1, 1), (6, 1), (1, 7)])
@pytest.mark.parametrize("row_filter", ["NONE", "SUB", "UP", "AVG", "PAETH"])
def test_gray_reader_on_opencv_pngs_of_every_filter(dtype, shape, row_filter):
    """None, Sub and Up (one filter for all rows) are decoded here, exactly as OpenCV does;
    Average and Paeth are left to OpenCV (None), and ``decode_image`` still returns the
    pixels."""
    image = _RNG.integers(0, np.iinfo(dtype).max + 1, shape, dtype=dtype)
    flag = getattr(cv2, f"IMWRITE_PNG_FILTER_{row_filter}")
    ok, buf = cv2.imencode(".png", image, [cv2.IMWRITE_PNG_FILTER, flag])
    assert ok
    data = buf.tobytes()
    decoded = decode_gray_png(data)
    if row_filter in ("AVG", "PAETH") and min(shape) > 1:
        assert decoded is None
    else:
        assert decoded is not None
        assert decoded.dtype == dtype
        np.testing.assert_array_equal(decoded, image)


def test_decode_image_reads_gray_pngs_of_any_filter(tmp_path):
    image = _CASES["gray16"]
    for row_filter in ("SUB", "PAETH"):
        flag = getattr(cv2, f"IMWRITE_PNG_FILTER_{row_filter}")
        path = tmp_path / f"{row_filter}.png"
        assert cv2.imwrite(str(path), image, [cv2.IMWRITE_PNG_FILTER, flag])
        np.testing.assert_array_equal(decode_image(path), image)


def _png(header: tuple[int, ...], idat: bytes, extra: bytes = b"") -> bytes:
    """A PNG from an IHDR tuple and an IDAT payload (zlib stream), with chunks ``extra``
    before the IDAT."""
    ihdr = _chunk(b"IHDR", struct.pack(">IIBBBBB", *header))
    return b"\x89PNG\r\n\x1a\n" + ihdr + extra + _chunk(b"IDAT", idat) + _chunk(b"IEND", b"")


def test_gray_reader_hands_over_what_it_does_not_decode():
    """Colour, transparency, a text chunk (skipped), bad CRCs, truncation, a filter type
    outside 0-4 and a stream longer than the header says: None, never an exception."""
    rows = np.zeros((4, 1 + 6), np.uint8)  # 4 rows of 3 16-bit pixels, filter None
    rows[:, 1:] = _RNG.integers(0, 256, (4, 6))
    good = _png((3, 4, 16, 0, 0, 0, 0), zlib.compress(rows.tobytes()))
    expected = rows[:, 1:].copy().view(">u2").astype(np.uint16)
    np.testing.assert_array_equal(decode_gray_png(good), expected)
    text = _chunk(b"tEXt", b"Software\x00test")
    np.testing.assert_array_equal(
        decode_gray_png(_png((3, 4, 16, 0, 0, 0, 0), zlib.compress(rows.tobytes()), text)),
        expected,
    )
    trns = _chunk(b"tRNS", b"\x00\x00")
    long_stream = zlib.compress(rows.tobytes() + b"\x00" * 7)
    bad_filter = rows.copy()
    bad_filter[2, 0] = 5
    mixed = rows.copy()
    mixed[1, 0] = 1
    refused = {
        "colour": png_bytes(_CASES["bgr8"]),
        "transparency": _png((3, 4, 16, 0, 0, 0, 0), zlib.compress(rows.tobytes()), trns),
        "interlaced": _png((3, 4, 16, 0, 0, 0, 1), zlib.compress(rows.tobytes())),
        "4-bit": _png((3, 4, 4, 0, 0, 0, 0), zlib.compress(rows.tobytes())),
        "crc": good[:-13] + bytes([good[-13] ^ 1]) + good[-12:],
        "truncated": good[: len(good) // 2],
        "not a png": b"GIF89a" + good[6:],
        "corrupt stream": _png((3, 4, 16, 0, 0, 0, 0), b"\x78\x9c garbage"),
        "too long": _png((3, 4, 16, 0, 0, 0, 0), long_stream),
        "too short": _png((3, 5, 16, 0, 0, 0, 0), zlib.compress(rows.tobytes())),
        "filter 5": _png((3, 4, 16, 0, 0, 0, 0), zlib.compress(bad_filter.tobytes())),
        "mixed filters": _png((3, 4, 16, 0, 0, 0, 0), zlib.compress(mixed.tobytes())),
    }
    for name, data in refused.items():
        assert decode_gray_png(data) is None, name


def test_a_corrupt_depth_png_is_still_one_clear_error(tmp_path):
    data = png_bytes(_CASES["gray16"])
    path = tmp_path / "depth.png"
    path.write_bytes(data[:60] + bytes(40) + data[100:])  # CRC and stream broken, IEND kept
    with pytest.raises(InputFileError, match="cannot decode PNG"):
        decode_image(path, frame=3)
