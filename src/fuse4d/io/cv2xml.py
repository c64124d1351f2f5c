"""The ``cv2-xml`` layout: per-frame colour, 16-bit depth, OpenCV FileStorage camera, mask.

Layout (one folder, frames numbered with any fixed number of digits, consecutive)::

    0000000000.jpg          colour or gray (.jpg or .png), converted to gray intensity
    0000000000_depth.png    uint16, millimetres by default (override: depth_unit_mm), 0 = invalid
    0000000000_camera.xml   OpenCV FileStorage with a 3x3 ``intrinsic`` matrix (px)
    0000000000_mask.jpg     optional object mask (gray >= 128 = True) -> GroundTruth.mask

This is the layout of the University of Amsterdam "CV2" RGB-D course data. The camera must be
the same in every frame (fuse4d assumes one fixed pinhole camera); other nodes (``R``, ``t``)
are ignored. If ``intrinsics=`` is given, the xml files are not read.
"""

from __future__ import annotations

import re
from os import PathLike
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from ..camera import Intrinsics
from ..errors import InputFileError
from ._base import Frame, FrameReader, IntrinsicsLike, depth_unit, resolve_intrinsics
from ._images import (
    check_frame_shape,
    decode_image,
    read_checked_intensity,
    read_depth_png,
    read_intensity_image,
    read_mask_image,
)

__all__ = ["Cv2XmlReader", "is_cv2_xml_folder", "read_cv2_xml_camera"]

_DEPTH = re.compile(r"^(\d+)_depth\.png$")
_COLOUR_EXT = (".jpg", ".png", ".jpeg")
_MASK_EXT = ("_mask.jpg", "_mask.png")


def is_cv2_xml_folder(path: Path) -> bool:
    """True if ``path`` holds ``NNNN_depth.png`` files next to ``NNNN_camera.xml`` files."""
    if not path.is_dir():
        return False
    for p in path.iterdir():
        m = _DEPTH.match(p.name)
        if m and (path / f"{m.group(1)}_camera.xml").exists():
            return True
    return False


def read_cv2_xml_camera(path: str | PathLike[str], *, frame: int | None = None) -> np.ndarray:
    """The 3x3 ``intrinsic`` matrix (px) of an OpenCV FileStorage file.

    Raises
    ------
    InputFileError
        If the file is missing, cannot be parsed, or has no valid 3x3 ``intrinsic`` node.
    """
    p = Path(path)
    if not p.is_file():
        raise InputFileError(p, "file not found", frame=frame)
    # OpenCV's parser reports malformed XML as cv2.error, or as SystemError (an error set
    # while returning a result) from the bindings.
    try:
        fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError):
        raise InputFileError(p, "cannot parse OpenCV FileStorage XML", frame=frame) from None
    try:
        if not fs.isOpened():
            raise InputFileError(p, "cannot parse OpenCV FileStorage XML", frame=frame)
        node = fs.getNode("intrinsic")
        mat = None if node.empty() else node.mat()
    except (cv2.error, SystemError):
        raise InputFileError(
            p, "cannot parse node 'intrinsic' (3x3 camera matrix)", frame=frame
        ) from None
    finally:
        fs.release()
    if mat is None:
        raise InputFileError(p, "missing node 'intrinsic' (3x3 camera matrix)", frame=frame)
    mat = np.asarray(mat, dtype=np.float64)
    if mat.shape != (3, 3) or not np.all(np.isfinite(mat)):
        raise InputFileError(
            p, f"node 'intrinsic' must be a finite 3x3 matrix, got shape {mat.shape}", frame=frame
        )
    return mat


class Cv2XmlReader(FrameReader):
    """Frame reader for the ``cv2-xml`` layout (see the module docstring).

    Parameters
    ----------
    path : str or PathLike
        The folder.
    depth_unit_mm : float, optional
        Millimetres per stored depth unit (default 1.0; the layout stores mm).
    intrinsics : IntrinsicsLike, optional
        Overrides the xml cameras.

    Raises
    ------
    InputFileError
        No ``*_depth.png``, a gap in the numbering, a missing colour/xml file, a camera that
        differs from frame 0's, masks for only some frames.
    """

    format = "cv2-xml"

    def __init__(
        self,
        path: str | PathLike[str],
        *,
        depth_unit_mm: float | None = None,
        intrinsics: IntrinsicsLike | None = None,
    ) -> None:
        self.path = root = Path(path)
        if not root.is_dir():
            raise InputFileError(root, "folder not found")
        found = sorted(
            (int(m.group(1)), m.group(1)) for p in root.iterdir() if (m := _DEPTH.match(p.name))
        )
        if not found:
            raise InputFileError(root, "no depth frames found (expected 0000000000_depth.png, ...)")
        first = found[0][0]
        for k, (num, stem) in enumerate(found):
            if num != first + k:
                expected = f"{first + k:0{len(stem)}d}_depth.png"
                raise InputFileError(
                    root / expected,
                    "file not found (frame numbers must be consecutive)",
                    frame=k,
                )
        self._stems = [stem for _, stem in found]
        self._colour = [self._find(stem, _COLOUR_EXT, k) for k, stem in enumerate(self._stems)]
        masks = [self._find(stem, _MASK_EXT, k, required=False) for k, stem in
                 enumerate(self._stems)]  # fmt: skip
        if any(m is not None for m in masks):
            for k, m in enumerate(masks):
                if m is None:
                    raise InputFileError(
                        root / f"{self._stems[k]}_mask.jpg",
                        "file not found (other frames have masks; give all or none)",
                        frame=k,
                    )
            self._masks: list[Path] | None = masks  # type: ignore[assignment]
            self.ground_truth_keys = ("mask",)
        else:
            self._masks = None
        unit = 1.0 if depth_unit_mm is None else float(depth_unit_mm)
        self.depth_unit_mm = depth_unit(unit)
        image = decode_image(root / f"{self._stems[0]}_depth.png", frame=0)
        h, w = image.shape[:2]
        self._matrix: np.ndarray | None = None
        if intrinsics is not None:
            self.intrinsics = resolve_intrinsics(intrinsics, width=w, height=h)
        else:
            self._matrix = read_cv2_xml_camera(self._xml(0), frame=0)
            try:
                self.intrinsics = Intrinsics.from_matrix(self._matrix, width=w, height=h)
            except ValueError as exc:
                raise InputFileError(self._xml(0), str(exc), frame=0) from None
            if self._matrix[0, 1] != 0:
                raise InputFileError(
                    self._xml(0), "camera matrix has a skew term; not supported", frame=0
                )
        self.notes = ("frame rate not stored in this layout",)

    def _find(
        self, stem: str, suffixes: tuple[str, ...], k: int, *, required: bool = True
    ) -> Path | None:
        for suffix in suffixes:
            p = self.path / f"{stem}{suffix}"
            if p.is_file():
                return p
        if required:
            raise InputFileError(
                self.path / f"{stem}{suffixes[0]}",
                f"file not found (colour image for {stem}_depth.png)",
                frame=k,
            )
        return None

    def _xml(self, k: int) -> Path:
        return self.path / f"{self._stems[k]}_camera.xml"

    def __len__(self) -> int:
        return len(self._stems)

    def read_frame(self, index: int) -> Frame:
        """Frame ``index``: depth (H, W) mm float32 (NaN invalid), intensity, mask."""
        k = self._index(index)
        if self._matrix is not None and k > 0:
            mat = read_cv2_xml_camera(self._xml(k), frame=k)
            if not np.allclose(mat, self._matrix, rtol=1e-6, atol=1e-6):
                raise InputFileError(
                    self._xml(k),
                    "camera differs from frame 0's; fuse4d needs one fixed camera "
                    "(pass intrinsics= to override)",
                    frame=k,
                )
        depth_path = self.path / f"{self._stems[k]}_depth.png"
        depth = read_depth_png(depth_path, frame=k, unit_mm=self.depth_unit_mm or 1.0)
        check_frame_shape(depth, self.shape, depth_path, k, against="frame 0")
        intensity = read_intensity_image(self._colour[k], frame=k)
        check_frame_shape(intensity, self.shape, self._colour[k], k, against="the depth frame")
        mask = None
        if self._masks is not None:
            mask = read_mask_image(self._masks[k], frame=k)
            check_frame_shape(mask, self.shape, self._masks[k], k, against="the depth frame")
        return Frame(k, depth, intensity, None, mask)

    def read_intensity(self, index: int) -> NDArray[np.float32]:
        """Frame ``index``'s intensity alone (no depth PNG, no camera file: :meth:`read_frame`
        checks those)."""
        k = self._index(index)
        return read_checked_intensity(self._colour[k], k, self.shape)
