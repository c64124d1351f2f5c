"""Decoding and encoding of single image files (PNG/JPEG) with explicit failure checks.

Files are read into memory by Python (so a missing file gives a clear error) and decoded with
``cv2.imdecode`` (``IMREAD_UNCHANGED`` keeps 16-bit PNGs); ``None`` from OpenCV, a missing PNG
end chunk or a missing JPEG end marker is reported as a truncated or corrupt file. Gray 8- and
16-bit PNGs (depth, and the flag images fuse4d writes) are decoded with ISA-L's inflate
(:func:`fuse4d.io._png.decode_gray_png`, the same array OpenCV returns); any PNG that decoder
does not take goes to OpenCV.
"""

from __future__ import annotations

import stat
import warnings
from collections.abc import Callable
from os import PathLike
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from ..errors import InputFileError
from ._png import decode_gray_png, png_bytes

__all__ = [
    "QuantizationReport",
    "check_frame_shape",
    "decode_image",
    "depth_to_units",
    "encode_png",
    "intensity_to_uint",
    "read_checked_intensity",
    "read_depth_png",
    "read_intensity_image",
    "read_mask_image",
]

_PNG_END = b"IEND\xaeB`\x82"
_JPEG_END = b"\xff\xd9"


#: Channels of each PNG colour type (IHDR byte 25): gray, RGB, palette, gray+alpha, RGBA.
_PNG_CHANNELS = {0: 1, 2: 3, 3: 1, 4: 2, 6: 4}


def _png_channels(path: str | PathLike[str]) -> int | None:
    """The channel count a PNG file's header states (None: not a PNG, or unreadable)."""
    try:
        with Path(path).open("rb") as f:
            head = f.read(26)
    except OSError:
        return None
    if len(head) < 26 or not head.startswith(b"\x89PNG\r\n\x1a\n"):
        return None
    return _PNG_CHANNELS.get(head[25])


def decode_image(
    path: str | PathLike[str], *, frame: int | None = None, jpeg_luma: bool = False
) -> np.ndarray:
    """Decode a PNG/JPEG/TIFF file unchanged (bit depth and channels kept).

    ``jpeg_luma``: decode a JPEG's luma plane only (one channel, bit depth kept). A colour JPEG
    stores luma Y = 0.299 R + 0.587 G + 0.114 B (ITU-R BT.601, JFIF) and two chroma planes;
    decoding Y alone skips the chroma upsampling, the conversion to BGR and the conversion
    back to gray (0.65 instead of 2.0 ms for a 640x480 frame of ``uva_cv2_person_turning``,
    whose gray values then differ from ``cv2.COLOR_BGR2GRAY``'s on 10 of 307 200 pixels, by
    1-4 levels: the rounding of the round trip). Other formats are decoded unchanged.

    Raises
    ------
    InputFileError
        If the file is missing, unreadable, truncated or not a decodable image.
    """
    p = Path(path)
    try:
        info = p.stat()
        if not stat.S_ISREG(info.st_mode):
            raise InputFileError(p, "not a regular file", frame=frame)
        if info.st_size > MAX_IMAGE_FILE_BYTES:
            raise InputFileError(
                p, f"file is {info.st_size} bytes; images over 1 GiB are refused", frame=frame
            )
        data = p.read_bytes()
    except FileNotFoundError:
        raise InputFileError(p, "file not found", frame=frame) from None
    except OSError as exc:
        raise InputFileError(p, f"cannot read file ({exc.strerror})", frame=frame) from None
    if not data:
        raise InputFileError(p, "file is empty", frame=frame)
    kind = "PNG" if data[:8] == b"\x89PNG\r\n\x1a\n" else "JPEG" if data[:2] == b"\xff\xd8" else ""
    size = _declared_size(data, kind)
    if size is not None and size[0] * size[1] > MAX_IMAGE_PIXELS:
        raise InputFileError(
            p,
            f"{kind} header declares {size[0]}x{size[1]} px; images over "
            f"{MAX_IMAGE_PIXELS} px are refused (corrupt header?)",
            frame=frame,
        )
    truncated = (kind == "PNG" and _PNG_END not in data[-64:]) or (
        kind == "JPEG" and _JPEG_END not in data[-64:]
    )
    if kind == "PNG" and not truncated:
        gray = decode_gray_png(data)  # gray 8/16-bit (depth): ISA-L's inflate
        if gray is not None:
            return gray
    flags = cv2.IMREAD_UNCHANGED
    if jpeg_luma and kind == "JPEG":
        # (any flag but IMREAD_UNCHANGED turns the image by its EXIF orientation: not here)
        flags = cv2.IMREAD_GRAYSCALE | cv2.IMREAD_ANYDEPTH | cv2.IMREAD_IGNORE_ORIENTATION
    image = None if truncated else cv2.imdecode(np.frombuffer(data, np.uint8), flags)
    if image is None:
        what = kind or "image"
        raise InputFileError(p, f"cannot decode {what} (truncated or corrupt file)", frame=frame)
    return image


#: Largest image accepted (px): 16k x 16k. Decoders allocate the declared size before
#: reading the data, so a corrupt header must not make them allocate gigabytes.
MAX_IMAGE_PIXELS = 1 << 28
#: Largest image file read into memory.
MAX_IMAGE_FILE_BYTES = 1 << 30


def _declared_size(data: bytes, kind: str) -> tuple[int, int] | None:
    """(width, height) from a PNG IHDR or a JPEG SOF marker; None if not found."""
    if kind == "PNG" and len(data) >= 24 and data[12:16] == b"IHDR":
        return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    if kind == "JPEG":
        pos = 2
        while pos + 9 < len(data):
            if data[pos] != 0xFF:
                return None
            marker = data[pos + 1]
            if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7:
                pos += 2
                continue
            length = int.from_bytes(data[pos + 2 : pos + 4], "big")
            if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):
                height = int.from_bytes(data[pos + 5 : pos + 7], "big")
                width = int.from_bytes(data[pos + 7 : pos + 9], "big")
                return width, height
            if marker == 0xDA or length < 2:  # start of scan: no SOF before it
                return None
            pos += 2 + length
    return None


def _size(image: np.ndarray) -> str:
    return f"{image.shape[1]}x{image.shape[0]}"


def read_depth_png(
    path: str | PathLike[str], *, frame: int | None = None, unit_mm: float = 1.0
) -> NDArray[np.float32]:
    """Read a 16-bit single-channel depth PNG as float32 mm (0 → NaN).

    Parameters
    ----------
    path : str or PathLike
        The PNG file.
    frame : int, optional
        Frame index, for error messages.
    unit_mm : float, optional
        Millimetres per stored unit (``value * unit_mm`` = mm).

    Returns
    -------
    depth : (H, W) ndarray of float32
        Depth in mm, NaN where the file holds 0.

    Raises
    ------
    InputFileError
        If the file cannot be decoded, has colour channels, or is not 16-bit.
    """
    image = decode_image(path, frame=frame)
    if image.ndim != 2:
        channels = _png_channels(path) or image.shape[2]  # OpenCV expands gray+alpha to 4
        raise InputFileError(
            path, f"depth image must have one channel, got {channels} channels", frame=frame
        )
    if image.dtype != np.uint16:
        bits = image.dtype.itemsize * 8
        raise InputFileError(
            path,
            f"depth PNG must be 16-bit (uint16), got {bits}-bit {image.dtype}; "
            "8-bit depth loses too much precision",
            frame=frame,
        )
    depth = image.astype(np.float32)
    if unit_mm != 1.0:
        depth *= np.float32(unit_mm)
        depth[(image == 0) | ~(depth > 0) | ~np.isfinite(depth)] = np.nan
    else:  # uint16 as float32 is exact, finite and > 0 unless 0: one test, no fancy index
        np.putmask(depth, image == 0, np.float32(np.nan))
    return depth


def read_intensity_image(
    path: str | PathLike[str], *, frame: int | None = None
) -> NDArray[np.float32]:
    """Read an 8- or 16-bit gray or colour image as float32 gray in [0, 1].

    Colour (BGR/BGRA as decoded by OpenCV) is converted with ``cv2.COLOR_BGR2GRAY``
    (ITU-R BT.601 luma); of a colour JPEG the luma plane it stores is decoded instead
    (:func:`decode_image`'s ``jpeg_luma``, the same weights without the round trip through
    BGR). Integers are divided by their dtype maximum (255 or 65535).

    Raises
    ------
    InputFileError
        If the file cannot be decoded or has an unsupported dtype/channel count.
    """
    image = _read_gray(path, frame=frame)
    scale = np.float32(1.0 / np.iinfo(image.dtype).max)
    return image.astype(np.float32) * scale


def read_mask_image(path: str | PathLike[str], *, frame: int | None = None) -> NDArray[np.bool_]:
    """Read a mask image (PNG or JPEG, any bit depth): True where gray >= half the dtype max.

    The threshold at 50 % (128 for 8-bit) makes JPEG ringing near the edges harmless.
    """
    gray = _read_gray(path, frame=frame)
    # the integer form of "gray / max >= 0.5" in float32: exact for 8 and 16 bits
    return gray >= (int(np.iinfo(gray.dtype).max) + 1) // 2


def _read_gray(path: str | PathLike[str], *, frame: int | None) -> NDArray[np.integer]:
    """The 8- or 16-bit gray image of :func:`read_intensity_image`, before scaling."""
    image = decode_image(path, frame=frame, jpeg_luma=True)
    if image.dtype not in (np.uint8, np.uint16):
        raise InputFileError(
            path, f"intensity image must be 8- or 16-bit, got {image.dtype}", frame=frame
        )
    if image.ndim == 3:
        channels = image.shape[2]
        if channels == 1:
            image = image[:, :, 0]
        elif channels == 3:
            image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        elif channels == 4:
            image = cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY)
        else:
            raise InputFileError(
                path, f"intensity image has {channels} channels (expected 1, 3 or 4)", frame=frame
            )
    return image


class QuantizationReport:
    """Accumulates what was lost when depth was rounded to integer units (warned once).

    Parameters
    ----------
    unit_mm : float
        Millimetres per stored unit.
    warn_coarse_unit : bool, optional
        Warn when the unit's rounding error (unit / sqrt 12) exceeds half the data's pixel
        noise (default True). False where the unit is the input recording's own (what
        ``fuse4d run`` and ``fuse4d live`` write back): the input was already stored at that
        precision, and a smoothed output (A42) is less noisy than its unit on any
        near-range surface, so the warning would fire on every run. Clipping is still reported.
    """

    def __init__(self, unit_mm: float, *, warn_coarse_unit: bool = True) -> None:
        self.unit_mm = float(unit_mm)
        self.warn_coarse_unit = bool(warn_coarse_unit)
        self.valid = 0
        self.clipped_high = 0
        self.clipped_low = 0
        self.off_grid = False
        self.noise_estimates: list[float] = []

    def add(self, depth: np.ndarray, stored: np.ndarray) -> None:
        """Record one frame: ``depth`` (H, W) mm float, ``stored`` the unit values before clip."""
        valid = np.isfinite(depth)
        n_valid = int(valid.sum())
        if not n_valid:
            self.valid += n_valid
            return
        s = stored[valid]
        units = depth[valid] / self.unit_mm
        self.add_counts(
            n_valid,
            int((s > 65535).sum()),
            int((s < 1).sum()),
            float(np.abs(units - np.round(units)).max()),
            lambda: depth,
        )

    def add_counts(
        self,
        n_valid: int,
        n_high: int,
        n_low: int,
        worst: float,
        depth: Callable[[], np.ndarray],
    ) -> None:
        """Record one frame from its tallies (what :meth:`add` computes).

        Parameters
        ----------
        n_valid, n_high, n_low : int
            Valid pixels, and those whose rounded unit value is > 65535 or < 1.
        worst : float
            Largest |depth / unit_mm - round(depth / unit_mm)| over the valid pixels (units).
        depth : callable
            Returns the frame (H, W) mm float64, NaN = invalid; called only for the first
            frames' noise estimate once values are off the unit grid.
        """
        self.valid += n_valid
        if not n_valid:
            return
        self.clipped_high += n_high
        self.clipped_low += n_low
        if not self.off_grid and worst > 1e-3:
            self.off_grid = True
        if self.warn_coarse_unit and self.off_grid and len(self.noise_estimates) < 8:
            frame = depth()
            diffs = np.abs(np.diff(frame, axis=1))
            diffs = diffs[np.isfinite(diffs)]
            if diffs.size >= 100:
                # robust per-pixel noise from horizontal neighbour differences (MAD, sqrt 2)
                self.noise_estimates.append(float(np.median(diffs)) * 1.4826 / np.sqrt(2.0))

    def warn(self, where: str, *, stacklevel: int = 4) -> None:
        """Emit one ``UserWarning`` if values were clipped or precision was badly lost
        (``stacklevel``: that of the caller's caller's caller, the user's ``with`` line)."""
        problems = []
        if self.clipped_high:
            problems.append(
                f"{self.clipped_high} depth values above {65535 * self.unit_mm:g} mm were clipped "
                f"to the 16-bit maximum (use a larger depth_unit_mm)"
            )
        if self.clipped_low:
            problems.append(
                f"{self.clipped_low} valid depth values below {0.5 * self.unit_mm:g} mm were "
                f"raised to 1 unit ({self.unit_mm:g} mm) so that they stay valid"
            )
        if self.off_grid and self.noise_estimates:
            noise = float(np.median(self.noise_estimates))
            rms = self.unit_mm / np.sqrt(12.0)
            # noise 0: most neighbours are equal (piecewise-constant data, e.g. the RealSense
            # chain's output), so the rounding has no noise to be compared with
            if noise > 0 and rms > 0.5 * noise:
                problems.append(
                    f"depth_unit_mm={self.unit_mm:g} is coarse for this data: rounding adds "
                    f"{rms:.3g} mm RMS error against an estimated pixel noise of {noise:.3g} mm "
                    f"(use a smaller depth_unit_mm or the .npz format)"
                )
        if problems:
            warnings.warn(f"{where}: " + "; ".join(problems), UserWarning, stacklevel=stacklevel)


def depth_to_units(
    depth: np.ndarray, unit_mm: float, report: QuantizationReport | None = None
) -> NDArray[np.uint16]:
    """Depth (H, W) mm (NaN/<=0 invalid) → uint16 units, rounded and clipped to [1, 65535].

    Invalid pixels become 0. Clipping and precision loss are recorded in ``report``.
    """
    arr = np.asarray(depth)
    if arr.ndim == 2 and arr.dtype in (np.float32, np.float64):
        # one pass, the same values as the numpy code below (issue 13: ~12 ms per 640x480
        # frame of boolean indexing in the write-behind thread, taken from the fusion)
        from .._kernels.io import _depth_to_units_kernel

        # contiguous: a strided view (points[..., 2]) would compile a second ('A' layout)
        # overload of the cached kernel, and concurrent cold runs race on numba's cache index
        arr = np.ascontiguousarray(arr)
        out = np.empty(arr.shape, dtype=np.uint16)
        counts = _depth_to_units_kernel(arr, float(unit_mm), out)
        if report is not None:

            def invalid_as_nan() -> np.ndarray:
                d = arr.astype(np.float64)
                return np.where(np.isfinite(d) & (d > 0), d, np.nan)

            report.add_counts(*counts, invalid_as_nan)
        return out
    return _depth_to_units_numpy(arr, unit_mm, report)


def _depth_to_units_numpy(
    depth: np.ndarray, unit_mm: float, report: QuantizationReport | None = None
) -> NDArray[np.uint16]:
    """:func:`depth_to_units` in numpy: the path for other dtypes and shapes, and the
    reference the one-pass kernel is tested against."""
    d = np.asarray(depth, dtype=np.float64)
    valid = np.isfinite(d) & (d > 0)
    d = np.where(valid, d, np.nan)
    stored = np.round(d / unit_mm)
    if report is not None:
        report.add(d, stored)
    out = np.zeros(d.shape, dtype=np.uint16)
    out[valid] = np.clip(stored[valid], 1, 65535).astype(np.uint16)
    return out


def intensity_to_uint(intensity: np.ndarray, bits: int) -> np.ndarray:
    """Intensity (H, W) in [0, 1] → uint8 or uint16 (rounded, clipped)."""
    top = 255 if bits == 8 else 65535
    dtype = np.uint8 if bits == 8 else np.uint16
    i = np.nan_to_num(np.asarray(intensity, dtype=np.float64), nan=0.0)
    return np.clip(np.round(i * top), 0, top).astype(dtype)


def encode_png(image: np.ndarray, path: str | PathLike[str]) -> None:
    """Write ``image`` (uint8/uint16, 2-D, BGR or BGRA) as PNG to exactly ``path`` (no
    atomicity here; ISA-L's deflate, :mod:`fuse4d.io._png`)."""
    Path(path).write_bytes(png_bytes(image))


def read_checked_intensity(
    path: str | PathLike[str], frame: int, shape: tuple[int, int]
) -> NDArray[np.float32]:
    """:func:`read_intensity_image` of frame ``frame`` at ``path``, checked to be ``shape``
    (H, W) like the recording's depth frames: the depth-free read of the image-file readers'
    ``read_intensity``."""
    intensity = read_intensity_image(path, frame=frame)
    check_frame_shape(intensity, shape, path, frame, against="the depth frames")
    return intensity


def check_frame_shape(
    image: np.ndarray,
    expected: tuple[int, int],
    path: str | PathLike[str],
    frame: int,
    *,
    against: str,
) -> None:
    """Raise :class:`InputFileError` unless ``image.shape[:2] == expected`` (H, W)."""
    shape = image.shape[:2]
    if shape != tuple(expected):
        raise InputFileError(
            path,
            f"image is {shape[1]}x{shape[0]} but {against} is {expected[1]}x{expected[0]} (WxH)",
            frame=frame,
        )
