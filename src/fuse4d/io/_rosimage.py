"""Decoding of ``sensor_msgs/Image`` and ``sensor_msgs/CompressedImage`` payloads to numpy.

Depth comes back as stored (uint16 units or float32 metres) so the caller applies the unit;
intensity comes back as a single-channel array (uint8, uint16 or float32) for the caller to
normalise. Every failure raises :class:`ValueError` with a plain message; the bag reader adds
the file, topic and frame.
"""

from __future__ import annotations

import struct

import cv2
import numpy as np

from ._png import decode_gray_png
from .rvl import decode_rvl

__all__ = [
    "DEPTH_ENCODINGS",
    "INTENSITY_ENCODINGS",
    "amplitude_to_gray",
    "decode_compressed",
    "decode_image_msg",
    "float_white_level",
    "image_kind",
    "normalise_intensity",
    "white_level",
]

#: ``sensor_msgs/Image`` encodings read as depth (``mono16`` is librealsense's Z16).
DEPTH_ENCODINGS = frozenset({"16uc1", "32fc1", "mono16"})
#: Encodings read as intensity (colour is converted to grey).
INTENSITY_ENCODINGS = frozenset(
    {"mono8", "8uc1", "mono16", "16uc1", "rgb8", "bgr8", "rgba8", "bgra8", "32fc1"}
)
_DTYPES = {
    "mono8": (np.uint8, 1), "8uc1": (np.uint8, 1), "mono16": (np.uint16, 1),
    "16uc1": (np.uint16, 1), "32fc1": (np.float32, 1), "rgb8": (np.uint8, 3),
    "bgr8": (np.uint8, 3), "rgba8": (np.uint8, 4), "bgra8": (np.uint8, 4),
}  # fmt: skip
_TO_GRAY = {
    "rgb8": cv2.COLOR_RGB2GRAY,
    "bgr8": cv2.COLOR_BGR2GRAY,
    "rgba8": cv2.COLOR_RGBA2GRAY,
    "bgra8": cv2.COLOR_BGRA2GRAY,
}


def image_kind(encoding_or_format: str) -> str:
    """Classify a message: ``"depth"``, ``"intensity"`` (grey/colour) or ``""`` (unusable).

    ``mono16`` counts as depth here (librealsense, Azure IR is told apart by its topic name).
    """
    text = encoding_or_format.strip().lower()
    if "compresseddepth" in text:
        return "depth"
    first = text.split(";")[0].strip()
    if first in DEPTH_ENCODINGS:
        return "depth"
    if first in INTENSITY_ENCODINGS or any(c in text for c in ("jpeg", "jpg", "png")):
        return "intensity"
    return ""


def decode_image_msg(msg: object, *, gray: bool = False) -> tuple[np.ndarray, str]:
    """Pixels of a ``sensor_msgs/Image``: ``(H, W)`` array (``gray`` converts colour).

    Returns
    -------
    array, encoding
        The array (a view on the message buffer where possible) and the lower-case encoding.
    """
    enc = str(msg.encoding).strip().lower()
    if enc not in _DTYPES:
        raise ValueError(f"unsupported image encoding {msg.encoding!r}")
    dtype, channels = _DTYPES[enc]
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    itemsize = np.dtype(dtype).itemsize
    row = w * channels * itemsize
    data = np.asarray(msg.data, dtype=np.uint8)
    if step < row or data.size < step * h or h < 1 or w < 1:
        raise ValueError(
            f"image data holds {data.size} bytes, too few for {w}x{h} {enc} (step {step})"
        )
    rows = data[: step * h].reshape(h, step)[:, :row]
    order = ">" if msg.is_bigendian and itemsize > 1 else "<"
    arr = rows.view(np.dtype(dtype).newbyteorder(order)) if itemsize > 1 else rows
    arr = arr.reshape(h, w, channels) if channels > 1 else arr.reshape(h, w)
    if order == ">":
        arr = arr.astype(np.dtype(dtype))
    if gray and channels > 1:
        arr = cv2.cvtColor(np.ascontiguousarray(arr), _TO_GRAY[enc])
    return arr, enc


def decode_compressed(msg: object, *, gray: bool = False) -> tuple[np.ndarray, str]:
    """Pixels of a ``sensor_msgs/CompressedImage``.

    ``compressedDepth`` (``compressed_depth_image_transport``): a 12-byte header (int32
    format, float32 ``depthQuantA``, ``depthQuantB``) then a 16-bit PNG, or for ``rvl`` two
    uint32 (width, height) and the RVL stream. For ``32FC1`` the PNG holds quantised inverse
    depth, returned as float32 metres (``A / (v - B)``, 0 = invalid). Other formats (JPEG/PNG
    colour or grey) are decoded with OpenCV.

    Returns
    -------
    array, encoding
        ``encoding`` is ``"16uc1"``/``"32fc1"`` for depth, ``"mono8"``/``"mono16"``/``"bgr8"``
        for images (``gray`` converts colour to ``mono8``).
    """
    fmt = str(msg.format).strip().lower()
    data = np.asarray(msg.data, dtype=np.uint8)
    if "compresseddepth" in fmt:
        return _decode_compressed_depth(fmt, data.tobytes())
    img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ValueError(f"cannot decode the {fmt!r} image (truncated or corrupt)")
    if img.ndim == 3:
        if gray:
            code = cv2.COLOR_BGRA2GRAY if img.shape[2] == 4 else cv2.COLOR_BGR2GRAY
            return cv2.cvtColor(img, code), "mono8"
        return img, "bgr8"
    return img, "mono16" if img.dtype == np.uint16 else "mono8"


def _decode_compressed_depth(fmt: str, raw: bytes) -> tuple[np.ndarray, str]:
    source = fmt.split(";")[0].strip()
    if len(raw) < 12:
        raise ValueError(f"compressedDepth message of {len(raw)} bytes has no 12-byte header")
    _, quant_a, quant_b = struct.unpack_from("<iff", raw, 0)
    body = raw[12:]
    if fmt.rstrip().endswith("rvl"):
        if len(body) < 8:
            raise ValueError("compressedDepth rvl message has no width/height")
        w, h = struct.unpack_from("<II", body, 0)
        if not (0 < w <= 1 << 15 and 0 < h <= 1 << 15):
            raise ValueError(f"compressedDepth rvl message has an invalid size {w}x{h}")
        img = decode_rvl(body[8:], w, h)
    else:
        img = decode_gray_png(body)  # ISA-L's inflate; None: OpenCV decodes (or reports)
        if img is None:
            img = cv2.imdecode(np.frombuffer(body, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise ValueError("cannot decode the compressedDepth PNG (truncated or corrupt)")
        if img.dtype != np.uint16 or img.ndim != 2:
            raise ValueError(f"compressedDepth PNG is {img.dtype} with shape {img.shape}")
    if source == "32fc1":
        inv = img.astype(np.float32)
        with np.errstate(divide="ignore", invalid="ignore"):
            metres = np.where(img > 0, quant_a / (inv - quant_b), 0.0).astype(np.float32)
        return metres, "32fc1"
    return img, "16uc1"


def white_level(image: np.ndarray) -> float:
    """The value mapped to intensity 1 for a 16-bit image (>= 1).

    The 99.5th percentile of the pixels that are neither 0 nor saturated (65535): IR images of
    ToF and stereo cameras use a small part of the 16-bit range and have saturated pixels
    (2.7 % in the Azure Kinect fixture), so neither 65535 nor the maximum makes a usable grey
    image. Taken once per file, on frame 0 as recorded (before any resampling), so that
    brightness stays constant over time whichever frames are read.
    """
    body = image[(image > 0) & (image < np.iinfo(np.uint16).max)]
    return max(float(np.percentile(body, 99.5)) if body.size else 65535.0, 1.0)


def float_white_level(image: np.ndarray) -> float | None:
    """The value mapped to intensity 1 for a float (``32FC1``) intensity image, or None.

    None when the image's finite values lie in [0, 1] (it is intensity already, kept as is).
    Else (IR amplitude in sensor units, e.g. 0-255 floats of ifm/pmd drivers) the 99.5th
    percentile of its finite pixels > 0, as :func:`white_level` for 16-bit images (>= 1).
    Taken once per file, on frame 0.
    """
    values = image[np.isfinite(image)]
    if not values.size or (values.min() >= 0 and values.max() <= 1):
        return None
    body = values[values > 0]
    return max(float(np.percentile(body, 99.5)) if body.size else 1.0, 1.0)


def normalise_intensity(image: np.ndarray, white: float | None) -> np.ndarray:
    """Single-channel image to float32 [0, 1]: uint8 / 255, uint16 / ``white``, float / ``white``
    where given (:func:`float_white_level`), else as is.

    Values above ``white`` (and saturated pixels, float +inf) become 1. Float NaN (no return)
    becomes 0; other float values are not clipped: the caller refuses those outside [0, 1]
    (negative, -inf, or above 1 without ``white``).
    """
    if image.dtype == np.uint8:
        return image.astype(np.float32) * np.float32(1.0 / 255.0)
    if image.dtype == np.uint16:
        scale = np.float32(1.0 / (white if white else 65535.0))
        return np.minimum(image.astype(np.float32) * scale, np.float32(1.0))
    out = np.array(image, dtype=np.float32)
    out[np.isnan(out)] = 0.0
    out[out == np.inf] = 1.0  # a saturated return
    if white:
        out = np.minimum(out * np.float32(1.0 / white), np.float32(1.0))
    return out


def amplitude_to_gray(image: np.ndarray, white: float) -> np.ndarray:
    """Time-of-flight IR amplitude (uint16) to float32 [0, 1]: ``sqrt(min(image / white, 1))``.

    A ToF camera's IR amplitude falls as 1 / z² and its noise is shot noise (variance
    proportional to the amplitude). Divided linearly by a white level set by a near, bright
    object, the rest of the scene is left in a few gray levels: in the Azure Kinect fixture a
    mug at 25 cm saturates and the 1.5-2 m background has a median of 0.0086 (about 2 of the
    flow's 256 levels). The square root (Anscombe's variance-stabilising transform) gives the
    noise one standard deviation at every brightness and the far scene its texture: on that
    frame, shifted by a known ~1 px flow with shot noise added, DIS's mean end-point error on
    the background fell from 0.81-1.50 px to 0.29-0.67 px, and on the mug it did not rise
    (``docs/method_notes.md``, "ToF IR mapping").
    """
    return np.sqrt(normalise_intensity(image, white))
