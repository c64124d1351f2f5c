"""Reading region-of-interest / object masks (e.g. for ``fuse4d metrics --roi``)."""

from __future__ import annotations

import zipfile
from os import PathLike
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..errors import InputFileError
from ._base import FrameSelection, resolve_frames
from ._images import read_mask_image
from .npz import MEMBER_ERRORS, read_member

__all__ = ["MASK_NPZ_KEYS", "read_mask"]

#: Keys tried, in order, when a mask is read from an ``.npz`` file.
MASK_NPZ_KEYS = ("roi", "mask", "mask_gt")


def read_mask(path: str | PathLike[str], *, frames: FrameSelection = None) -> NDArray[np.bool_]:
    """Read a boolean mask (True = inside) from an image, an ``.npz`` or a recording.

    Parameters
    ----------
    path : str or PathLike
        - an image (PNG/JPEG/TIFF, any bit depth): True where gray >= 50 % of the dtype
          maximum, giving ``(H, W)``;
        - an ``.npz``: the first of the keys ``roi``, ``mask``, ``mask_gt`` (bool, or nonzero
          = True), giving ``(H, W)`` or ``(T, H, W)``;
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
    if p.suffix.lower() == ".npz":
        mask = _npz_mask(p)
        if mask.ndim == 3:
            sel = resolve_frames(frames, mask.shape[0])
            mask = mask[sel.start : sel.stop]
        elif mask.ndim != 2:
            raise InputFileError(p, f"mask must be (H, W) or (T, H, W), got shape {mask.shape}")
        return mask
    return read_mask_image(p)


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
    if array.dtype.kind not in "biuf" or array.dtype.names is not None:
        raise InputFileError(p, f"mask must hold numbers or booleans, got dtype {array.dtype}")
    return np.asarray(array) != 0
