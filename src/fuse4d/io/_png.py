"""PNG encoding with ISA-L's deflate: the frames that ``fuse4d run`` writes, 5x faster.

A PNG is a signature and three chunks (IHDR: size and pixel format, IDAT: the zlib stream of
the filtered rows, IEND), each with its CRC-32 (PNG specification, W3C 2003/2022). What costs
time is the deflate of the IDAT. OpenCV's and Pillow's PNG writers call the zlib they were
built with (zlib 1.2.11 for this machine's OpenCV); no PNG library can be told to use another
deflate. ISA-L (Intel's storage acceleration library, through ``isal``) writes the same zlib
format 4x faster than zlib at level 1 and as small, so fuse4d assembles the chunks itself
(about twenty lines) around ``isal_zlib.compress``. Decoding stays with OpenCV.

Measured on 640 x 480 frames of ``uva_cv2_person_turning`` fused by ``fuse4d run`` (one
sitting, best of 5, stop 38), against OpenCV with zlib level 1, the Paeth filter and RLE (the
settings of stops 33-37): depth 4.67 -> 1.03 ms, 8-bit intensity 3.69 -> 0.70 ms, mask
0.68 -> 0.06 ms, source 0.92 -> 0.16 ms, confidence 1.37 -> 0.29 ms, i.e. 11.3 -> 2.2 ms a
frame; the files are 17 % larger (274 -> 321 kB a frame; depth 119 -> 131 kB, intensity
114 -> 134 kB). Every row takes the Up filter (the byte minus the one above it): one numpy
subtraction, and within 2 % of the size Paeth gives with ISA-L.
"""

from __future__ import annotations

import struct
import sys

import numpy as np
from isal import isal_zlib

__all__ = ["decode_gray_png", "png_bytes"]

_SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: channels -> PNG colour type (gray, RGB, RGBA)
_COLOR_TYPE = {1: 0, 3: 2, 4: 6}
#: OpenCV's channel order (BGR, BGRA) -> the PNG's (RGB, RGBA)
_TO_RGB = {3: [2, 1, 0], 4: [2, 1, 0, 3]}
#: ISA-L level 1: the same size as levels 2-3 on these frames, and the fastest
_LEVEL = 1
_FILTER_NONE, _FILTER_SUB, _FILTER_UP = 0, 1, 2
#: the row filters that are running sums modulo 256 (numpy's cumsum in uint8); Average and
#: Paeth need a loop per byte
_CUMULATIVE_FILTERS = (_FILTER_NONE, _FILTER_SUB, _FILTER_UP)


def png_bytes(image: np.ndarray) -> bytes:
    """The PNG file of ``image``, lossless.

    Parameters
    ----------
    image : (H, W), (H, W, 3) or (H, W, 4) ndarray of uint8 or uint16
        Gray, BGR or BGRA (OpenCV's channel order, as ``cv2.imencode`` takes it).

    Returns
    -------
    bytes
        A PNG (8 or 16 bits per sample, not interlaced) that decodes to ``image``.

    Raises
    ------
    ValueError
        For another dtype or shape, or an empty image.

    Examples
    --------
    >>> import cv2
    >>> depth = np.arange(12, dtype=np.uint16).reshape(3, 4) * 5000
    >>> data = png_bytes(depth)
    >>> data[:8] == b"\\x89PNG\\r\\n\\x1a\\n"
    True
    >>> bool((cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED) == depth).all())
    True
    """
    a = np.asarray(image)
    if a.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"PNG takes uint8 or uint16 images, got {a.dtype}")
    channels = 1 if a.ndim == 2 else (a.shape[2] if a.ndim == 3 else 0)
    if channels not in _COLOR_TYPE:
        raise ValueError(f"PNG takes (H, W), (H, W, 3) or (H, W, 4) images, got {a.shape}")
    h, w = a.shape[:2]
    if h == 0 or w == 0:
        raise ValueError(f"cannot write an empty {w}x{h} image as PNG")
    if channels > 1:
        a = a[..., _TO_RGB[channels]]
    rows = a.reshape(h, w * channels)
    if a.dtype == np.uint16:  # PNG stores 16-bit samples big-endian
        rows = rows.astype(">u2").view(np.uint8)
    filtered = np.empty((h, rows.shape[1] + 1), np.uint8)
    filtered[:, 0] = _FILTER_UP
    filtered[0, 1:] = rows[0]  # the row above the first is zero
    np.subtract(rows[1:], rows[:-1], out=filtered[1:, 1:])  # modulo 256
    header = struct.pack(">IIBBBBB", w, h, 8 * a.itemsize, _COLOR_TYPE[channels], 0, 0, 0)
    return b"".join(
        (
            _SIGNATURE,
            _chunk(b"IHDR", header),
            _chunk(b"IDAT", isal_zlib.compress(filtered, _LEVEL)),
            _chunk(b"IEND", b""),
        )
    )


def _chunk(kind: bytes, data: bytes) -> bytes:
    """One PNG chunk: length, type, data, CRC-32 of type and data."""
    crc = isal_zlib.crc32(data, isal_zlib.crc32(kind))
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", crc)


#: chunks a gray PNG may hold beside IHDR, IDAT and IEND that change nothing OpenCV decodes
#: (text, time, physical size); any other (tRNS, sBIT, gAMA, ...) goes to OpenCV
_PLAIN_CHUNKS = frozenset((b"tEXt", b"zTXt", b"iTXt", b"tIME", b"pHYs"))
#: larger images (bytes of filtered rows) go to OpenCV (which refuses absurd sizes)
_MAX_SIZE = 1 << 30


def decode_gray_png(data: bytes) -> np.ndarray | None:
    """Decode a gray 8- or 16-bit PNG with ISA-L's inflate, or None where it does not apply.

    The read-side counterpart of :func:`png_bytes`: what costs time in decoding a depth PNG
    is the inflate (zlib 2.0 ms, ISA-L 0.8-0.9 ms for a 640 x 480 frame of
    ``uva_cv2_person_turning``), and OpenCV's decoder cannot be given another inflate. The
    row filters are undone with numpy where every row has the same one of None, Sub or Up
    (running sums modulo 256): OpenCV writes 16-bit PNGs with Sub on every row (the depth of
    ``uva_cv2_person_turning`` and ``static_room_rgbd``), :func:`png_bytes` with Up. Other
    filters (Average, Paeth, a filter chosen per row) go to OpenCV, as does anything else
    unusual, so that no numba kernel has to be loaded for a PNG (``fuse4d info`` starts in
    0.4 s).

    Parameters
    ----------
    data : bytes
        A whole PNG file.

    Returns
    -------
    (H, W) ndarray of uint8 or uint16, or None
        The image as ``cv2.imdecode(..., IMREAD_UNCHANGED)`` returns it, or None where this
        decoder does not apply: another colour type or bit depth, interlacing, a chunk that
        could change the decoded values (only text, time and pHYs are skipped), row filters
        other than one of None, Sub, Up for all rows, a CRC or length mismatch, a corrupt
        stream. The caller then decodes with OpenCV, which reports a corrupt file.
    """
    if data[:8] != _SIGNATURE:
        return None
    pos, end = 8, len(data)
    header = None
    idat: list[bytes] = []
    while pos + 12 <= end:
        (length,) = struct.unpack_from(">I", data, pos)
        kind = data[pos + 4 : pos + 8]
        stop = pos + 8 + length
        if stop + 4 > end:
            return None
        body = data[pos + 8 : stop]
        (crc,) = struct.unpack_from(">I", data, stop)
        if isal_zlib.crc32(body, isal_zlib.crc32(kind)) != crc:
            return None
        if kind == b"IHDR":
            if header is not None or length != 13:
                return None
            header = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat.append(body)
        elif kind == b"IEND":
            break
        elif kind not in _PLAIN_CHUNKS:
            return None
        pos = stop + 4
    else:
        return None  # no IEND
    if header is None or not idat:
        return None
    width, height, bits, colour, method, filtering, interlace = header
    if colour != 0 or bits not in (8, 16) or (method, filtering, interlace) != (0, 0, 0):
        return None
    bpp = bits // 8
    stride = width * bpp
    size = height * (stride + 1)
    if width == 0 or height == 0 or size > _MAX_SIZE:
        return None
    inflate = isal_zlib.decompressobj()
    try:  # at most one byte more than the header says (a corrupt stream can inflate to GBs)
        raw = inflate.decompress(b"".join(idat), size + 1)
    except isal_zlib.error:
        return None
    if len(raw) != size or not inflate.eof:
        return None
    rows = np.frombuffer(raw, np.uint8).reshape(height, stride + 1)
    row_filter = int(rows[0, 0])
    if row_filter not in _CUMULATIVE_FILTERS or not (rows[:, 0] == row_filter).all():
        return None
    samples = rows[:, 1:].reshape(height, width, bpp)
    out = np.empty((height, width), np.uint8 if bits == 8 else np.uint16)
    # the running sums go straight into the result's bytes, most significant first
    lanes = out.view(np.uint8).reshape(height, width, bpp)
    if bpp == 2 and sys.byteorder == "little":
        lanes = lanes[..., ::-1]
    if row_filter == _FILTER_NONE:
        lanes[...] = samples
    elif row_filter == _FILTER_SUB:  # each byte + the same byte of the pixel to its left
        np.cumsum(samples, axis=1, dtype=np.uint8, out=lanes)
    else:  # Up: each byte + the byte above
        np.cumsum(samples, axis=0, dtype=np.uint8, out=lanes)
    return out
