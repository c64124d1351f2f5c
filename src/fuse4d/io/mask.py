"""Reading region-of-interest / object masks (e.g. for ``fuse4d metrics --roi``)."""

from __future__ import annotations

import math
import zipfile
from os import PathLike
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..errors import InputFileError
from ._base import FrameSelection, resolve_frames
from ._images import read_mask_image
from .npz import MEMBER_ERRORS, _read_npy_header, read_member

__all__ = ["MASK_NPZ_KEYS", "read_mask"]

#: Keys tried, in order, when a mask is read from an ``.npz`` file.
MASK_NPZ_KEYS = ("roi", "mask", "mask_gt")

#: What a mask can be read from, for the message of a file that is none of them.
_MASK_SOURCES = (
    "a mask is read from an image (PNG, JPEG, TIFF), an .npz, an .npy or a recording folder "
    "with masks"
)


def read_mask(path: str | PathLike[str], *, frames: FrameSelection = None) -> NDArray[np.bool_]:
    """Read a boolean mask (True = inside) from an image, an ``.npz`` or a recording.

    Parameters
    ----------
    path : str or PathLike
        - an image (PNG/JPEG/TIFF, any bit depth): True where gray >= 50 % of the dtype
          maximum, giving ``(H, W)``;
        - an ``.npz``: the first of the keys ``roi``, ``mask``, ``mask_gt``, or an ``.npy``
          (bool, or numbers with nonzero = True; NaN is refused as neither), giving
          ``(H, W)`` or ``(T, H, W)``;
        - a recording whose layout stores object masks (frame folder with ``mask/``,
          ``cv2-xml`` with ``*_mask.jpg``): the per-frame masks, ``(T, H, W)``.
    frames : slice, range, (start, stop), "A:B" or None, optional
        Frame range, applied to ``(T, H, W)`` masks only.

    Returns
    -------
    mask : (H, W) or (T, H, W) ndarray of bool

    Raises
    ------
    InputFileError
        If nothing mask-like is found or the file is unreadable.
    """
    p = Path(path)
    if p.is_dir():
        from .api import open_frames  # local import: api imports the readers

        with open_frames(p) as reader:
            if "mask" not in reader.ground_truth_keys:
                raise InputFileError(p, "this recording stores no masks")
            sel = resolve_frames(frames, len(reader))
            return np.stack([reader.read_frame(k).mask for k in sel])  # type: ignore[misc]
    if p.suffix.lower() in (".npz", ".npy"):
        mask = _npz_mask(p) if p.suffix.lower() == ".npz" else _npy_mask(p)
        if mask.ndim == 3:
            sel = resolve_frames(frames, mask.shape[0])
            mask = mask[sel.start : sel.stop]
        elif mask.ndim != 2:
            raise InputFileError(p, f"mask must be (H, W) or (T, H, W), got shape {mask.shape}")
        return mask
    try:
        return read_mask_image(p)
    except InputFileError as exc:
        if "cannot decode image" not in exc.problem:
            raise
        raise InputFileError(p, f"{exc.problem}; {_MASK_SOURCES}") from None


def _npz_mask(p: Path) -> NDArray[np.bool_]:
    try:
        with zipfile.ZipFile(p) as zf:
            members = {Path(n).stem: n for n in zf.namelist() if n.endswith(".npy")}
            key = next((k for k in MASK_NPZ_KEYS if k in members), None)
            if key is None:
                raise InputFileError(
                    p,
                    f"no mask key: needs a key 'mask' or 'roi' (or 'mask_gt'), "
                    f"found {sorted(members)}",
                )
            array = read_member(zf, members[key])
    except InputFileError:
        raise
    except FileNotFoundError:
        raise InputFileError(p, "file not found") from None
    except MEMBER_ERRORS as exc:
        raise InputFileError(p, f"not a valid .npz file (truncated or corrupt: {exc})") from None
    return _as_mask(p, array)


def _npy_mask(p: Path) -> NDArray[np.bool_]:
    """The mask of an ``.npy`` file (no pickles; a header declaring more data than the file
    holds is refused before numpy allocates it)."""
    try:
        with p.open("rb") as f:
            header = _read_npy_header(f)
            if header is not None:
                shape, _, dtype = header
                if dtype.hasobject:
                    raise ValueError("object arrays are not allowed")
                if f.tell() + math.prod(shape) * dtype.itemsize > p.stat().st_size:
                    raise ValueError("the file is shorter than its header declares")
            f.seek(0)
            array = np.lib.format.read_array(f, allow_pickle=False)
    except FileNotFoundError:
        raise InputFileError(p, "file not found") from None
    except MEMBER_ERRORS as exc:
        raise InputFileError(p, f"not a valid .npy file (truncated or corrupt: {exc})") from None
    return _as_mask(p, array)


def _as_mask(p: Path, array: np.ndarray) -> NDArray[np.bool_]:
    """Bool mask of a stored array: bool as it is, numbers nonzero = True; NaN refused (it is
    neither in nor out)."""
    if array.dtype.kind not in "biuf" or array.dtype.names is not None:
        raise InputFileError(p, f"mask must hold numbers or booleans, got dtype {array.dtype}")
    if array.dtype.kind == "f" and (nans := int(np.isnan(array).sum())):
        raise InputFileError(
            p, f"mask holds {nans} NaN values: give bool, or numbers with nonzero = inside"
        )
    return np.asarray(array) != 0
