"""Resumable frame-folder output: a run killed at any frame continues with ``--resume``.

While ``fuse4d run IN -o OUT`` writes a frame folder, the frames go to ``OUT.partial/``:

* each frame's PNGs are written under temporary names and renamed into place, then the
  manifest ``fuse4d-run.json`` (written the same way) counts the frame as done, so a kill at
  any point leaves complete frames, the manifest, and at most one temporary file (removed on
  Ctrl-C, and by the next ``--resume`` after a hard kill);
* every :data:`CHECKPOINT_EVERY` frames the manifest records a *checkpoint*: the frame to
  restart from and the warm-start flow the fusion engine needs there (``resume/seed-*.npy``),
  so the resumed run equals an uninterrupted one bit for bit (every decoded sample; the PNGs'
  compressed bytes may differ, as ISA-L's deflate output is not byte-reproducible from one
  process to another);
* ``camera.json`` (which makes the folder readable) is written last, then ``OUT.partial`` is
  renamed to ``OUT``. The manifest stays in ``OUT`` with ``"complete": true``.

The manifest holds the input's fingerprint, the parameters, fuse4d's and its libraries'
versions: ``--resume`` refuses to continue a run whose input, parameters or versions differ.
It holds no path that fuse4d opens: the file names inside ``OUT.partial`` are fixed.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import shutil
import sys
import time
from collections.abc import Iterator
from os import PathLike
from pathlib import Path
from types import TracebackType
from typing import Any, Self

import numpy as np

from ..camera import Intrinsics
from ..errors import InputFileError, OutputExistsError, ParameterError
from ._atomic import _create_temp, _replace_existing, check_output, write_errors
from ._base import check_flags, flag_images
from ._images import QuantizationReport, depth_to_units, encode_png
from .folder import camera_json_text, intensity_image

__all__ = [
    "CHECKPOINT_EVERY",
    "MANIFEST_NAME",
    "ResumableFolderWriter",
    "fingerprint_input",
    "partial_path",
    "run_identity",
    "run_parameters",
    "run_reader_options",
    "run_seconds",
    "run_steady_ms",
    "unfinished_run_message",
]

#: Name of the manifest inside the output (and partial) folder.
MANIFEST_NAME = "fuse4d-run.json"
#: Frames between two checkpoints (a resumed run recomputes at most this many + the window).
CHECKPOINT_EVERY = 8
_FORMAT = 1
_INDEX_SUFFIXES = {".json", ".txt", ".xml", ".toml", ".csv"}


def partial_path(path: str | PathLike[str]) -> Path:
    """The folder where an unfinished run of ``path`` lives (``OUT.partial``)."""
    p = Path(path)
    return p.with_name(p.name + ".partial")


def fingerprint_input(path: str | PathLike[str]) -> str:
    """SHA-256 over the input's file names, sizes and modification times, and the contents
    of its index files (``.json``, ``.txt``, ``.xml``, ...). Cheap: frames are not read.

    Symbolic links are not followed into folders (no loops).
    """
    root = Path(path)
    digest = hashlib.sha256()
    files = [root] if root.is_file() else sorted(_walk(root))
    for f in files:
        rel = f.name if f == root else f.relative_to(root).as_posix()
        try:
            st = f.stat()
        except OSError:
            continue
        digest.update(f"{rel}\0{st.st_size}\0{st.st_mtime_ns}\n".encode())
        if f.suffix.lower() in _INDEX_SUFFIXES and st.st_size <= 16 << 20:
            with f.open("rb") as handle:
                digest.update(hashlib.sha256(handle.read()).digest())
    return digest.hexdigest()


def _walk(root: Path) -> Iterator[Path]:
    for folder, dirs, names in os.walk(root, followlinks=False):
        dirs.sort()
        for name in names:
            yield Path(folder) / name


def run_identity(
    input: str | PathLike[str],
    *,
    frames: int,
    shape: tuple[int, int],
    depth_unit_mm: float | None,
    fusion: dict[str, Any],
    flow: dict[str, Any],
    reader_options: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Everything a resumed run must share with the run it continues.

    ``reader_options`` (the :func:`fuse4d.io.open_frames` options that chose the streams,
    camera and frame range, e.g. ``{"frames": "200:300"}``) are recorded where any was given,
    so that ``fuse4d report`` reads the input as the run did (:func:`run_reader_options`).
    """
    from .. import __version__

    versions = {"fuse4d": __version__, "python": sys.version.split()[0]}
    for name in ("numpy", "numba", "cv2"):
        module = sys.modules.get(name)
        versions[name] = getattr(module, "__version__", None) if module else None
    identity = {
        "input_fingerprint": fingerprint_input(input),
        "frames": int(frames),
        "shape": list(shape),
        "depth_unit_mm": depth_unit_mm,
        "fusion": fusion,
        "flow": flow,
        "versions": versions,
    }
    if reader_options:
        identity["reader_options"] = dict(reader_options)
    return _canonical(identity)


def _canonical(value: Any) -> Any:
    """A JSON round trip (so that stored and fresh identities compare equal)."""
    return json.loads(json.dumps(value, sort_keys=True, default=str))


def _identity_diff(want: dict[str, Any], have: dict[str, Any]) -> list[str]:
    """The keys (sorted) in which two run identities (:func:`run_identity`) differ."""
    return sorted(k for k in set(want) | set(have) if want.get(k) != have.get(k))


def _read_manifest(folder: Path) -> dict[str, Any] | None:
    path = folder / MANIFEST_NAME
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        return None
    except (OSError, ValueError) as exc:
        raise InputFileError(path, f"unreadable run manifest ({exc})") from None
    if not isinstance(data, dict) or data.get("format") != _FORMAT:
        raise InputFileError(path, "not a fuse4d run manifest (unknown format)")
    return data


def _finished_run(folder: str | PathLike[str]) -> dict[str, Any]:
    """The manifest of the finished ``fuse4d run`` in ``folder``; ``{}`` for a folder without
    one (not a run's output, or an unfinished run)."""
    data = _read_manifest(Path(folder))
    return data if data is not None and data.get("complete") else {}


def run_parameters(folder: str | PathLike[str]) -> dict[str, Any] | None:
    """The fusion parameters (and ``flow_method``) that a finished ``fuse4d run`` wrote into
    the manifest of its output folder, for ``fuse4d report``; None for a folder without a
    finished run's manifest."""
    identity = _finished_run(folder).get("identity") or {}
    fusion, flow = identity.get("fusion"), identity.get("flow") or {}
    if not isinstance(fusion, dict):
        return None
    return {**fusion, "flow_method": flow.get("method", "")}


def run_reader_options(folder: str | PathLike[str]) -> dict[str, Any]:
    """The reader options (streams, camera, frame range) with which a finished ``fuse4d run``
    read its input, from the manifest of its output folder; ``{}`` where none was given or
    the folder holds no finished run."""
    options = (_finished_run(folder).get("identity") or {}).get("reader_options")
    return dict(options) if isinstance(options, dict) else {}


def run_seconds(folder: str | PathLike[str]) -> float | None:
    """Wall time (s) of the finished ``fuse4d run`` whose output is ``folder`` (I/O included;
    the parts of a resumed run added up), for the report's time per frame; None where the
    manifest does not say (no finished run, or written by an older fuse4d)."""
    seconds = _finished_run(folder).get("seconds")
    return float(seconds) if isinstance(seconds, int | float) else None


def run_steady_ms(folder: str | PathLike[str]) -> float | None:
    """Wall time per frame once running (ms, I/O included) of the finished ``fuse4d run``
    whose output is ``folder`` (:attr:`fuse4d.RunSummary.steady_ms_per_frame`; of the last
    session of a resumed run), for the report; None where the manifest does not say (too few
    frames, or written by an older fuse4d)."""
    steady = _finished_run(folder).get("steady_ms_per_frame")
    return float(steady) if isinstance(steady, int | float) else None


def unfinished_run_message(folder: Path) -> str:
    """A message if ``folder`` holds an unfinished run (for readers), else ``""``."""
    try:
        data = _read_manifest(folder)
    except InputFileError:
        return ""
    if not data or data.get("complete"):
        return ""
    done, total = data.get("frames_done"), data.get("identity", {}).get("frames")
    return (
        f"unfinished fuse4d run ({done} of {total} frames written); finish it with the same "
        "`fuse4d run ... --resume` command"
    )


def _write_json_atomic(path: Path, data: dict[str, Any]) -> None:
    text = json.dumps(data, indent=1, sort_keys=True) + "\n"
    _write_atomic(path, lambda tmp: tmp.write_text(text, encoding="utf-8"))


def _write_atomic(path: Path, write: Any) -> None:
    """``write(tmp_path)`` then rename onto ``path``; the temporary is removed on any error."""
    tmp = _create_temp(path, directory=False)
    try:
        write(tmp)
        tmp.replace(path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def _save_npy(path: Path, array: np.ndarray) -> None:
    with path.open("wb") as f:  # a file object: np.save would append ".npy" to a name
        np.save(f, np.ascontiguousarray(array), allow_pickle=False)


class ResumableFolderWriter:
    """Frame-folder writer whose output survives a kill and can be continued (module doc).

    Parameters
    ----------
    path : str or PathLike
        Destination folder; frames are staged in :func:`partial_path` ``(path)``.
    intrinsics : Intrinsics
        Camera; frames must be ``(intrinsics.height, intrinsics.width)``.
    identity : dict
        :func:`run_identity` of this run (stored in, and compared with, the manifest).
    depth_unit_mm, fps, warn_coarse_unit, sensor
        As for :class:`~fuse4d.io.FrameFolderWriter`.
    overwrite : bool
        Replace an existing ``path`` and discard an existing unfinished run.
    resume : bool
        Continue the unfinished run in ``path.partial`` (if there is none, start one). Where
        ``path`` already holds the finished run of the same identity, nothing is to be done
        (:attr:`already_complete`; don't open the writer), as a rerun of a batch script with
        ``--resume`` expects (``--engine dask`` alike); a finished run of another identity is
        a ParameterError naming what differs.

    Attributes
    ----------
    already_complete : bool
        ``resume`` found this run finished in ``path``.
    frames_done : int
        Frames complete on disk (the next :meth:`write` writes this frame).
    restart_frame : int
        Frame from which the caller must produce output again (the last checkpoint;
        ``<= frames_done``); frames before ``frames_done`` are already on disk.
    seed : ndarray or None
        Warm-start flow stored with the checkpoint (``FusionEngine(initial_flow=...)``).
    """

    #: :meth:`write` stores a fused frame's per-pixel ``source`` and ``confidence``.
    stores_flags = True

    def __init__(
        self,
        path: str | PathLike[str],
        intrinsics: Intrinsics,
        *,
        identity: dict[str, Any],
        depth_unit_mm: float = 1.0,
        fps: float | None = None,
        overwrite: bool = False,
        resume: bool = False,
        checkpoint_every: int = CHECKPOINT_EVERY,
        warn_coarse_unit: bool = True,
        sensor: str | None = None,
    ) -> None:
        if not (math.isfinite(depth_unit_mm) and depth_unit_mm > 0):
            raise ParameterError(f"depth_unit_mm must be > 0, got {depth_unit_mm!r}")
        self.path = Path(path)
        self.identity = _canonical(identity)
        self.already_complete = False
        if self.path.exists() and not overwrite:
            if not (resume and self._finished_here()):
                raise OutputExistsError(self.path)
            self.already_complete = True
        check_output(self.path, overwrite=True, probe=not self.already_complete)
        self.partial = partial_path(self.path)
        self.intrinsics = intrinsics
        self.depth_unit_mm = float(depth_unit_mm)
        self.fps = fps
        self.sensor = sensor  # the camera kind, kept in camera.json (A36 on a later run)
        self.overwrite = overwrite
        self.resume = resume
        self.checkpoint_every = max(1, int(checkpoint_every))
        self.frames_done = 0
        self.restart_frame = 0
        self.seed: np.ndarray | None = None
        self._has_mask: bool | None = None
        self._checkpoint: dict[str, Any] | None = None
        self._report = QuantizationReport(self.depth_unit_mm, warn_coarse_unit=warn_coarse_unit)
        self._open = False
        # wall time of the run: the parts of a resumed run before this one, and since open()
        self._seconds_before = 0.0
        self._opened_at: float | None = None
        self._steady_ms: float | None = None  # set_steady_rate

    def set_steady_rate(self, ms_per_frame: float) -> None:
        """The run's wall time per frame once running (ms, I/O included; of this session for
        a resumed run), stored in the finished run's manifest for a later ``fuse4d report``
        (:func:`run_steady_ms`). Not stored when NaN (too few frames)."""
        self._steady_ms = float(ms_per_frame) if math.isfinite(ms_per_frame) else None

    def _finished_here(self) -> bool:
        """Whether ``path`` holds the finished run of this identity (False: no run's manifest
        there, so not ours to judge); ParameterError for a finished run of another one."""
        if not self.path.is_dir():
            return False
        data = _finished_run(self.path)
        if not data:
            return False
        diff = _identity_diff(self.identity, data.get("identity") or {})
        if diff:
            raise ParameterError(
                f"{self.path}: holds a finished run whose {', '.join(diff)} differ from this "
                "one's; use --force to replace it, or another output"
            )
        return True

    # ------------------------------------------------------------------ life cycle
    def __enter__(self) -> Self:
        self.open()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if exc_type is None:
            self.close()
            return
        self._open = False
        if self.frames_done == 0 and self._checkpoint is None:
            shutil.rmtree(self.partial, ignore_errors=True)  # nothing worth keeping

    def open(self) -> None:
        """Start a new run in ``path.partial`` or pick up the unfinished one (``resume``)."""
        self._opened_at = time.perf_counter()
        with write_errors(self.partial):
            if self.partial.exists() and not self.resume:
                if not self.overwrite:
                    raise ParameterError(
                        f"{self.partial}: an unfinished run of this output exists; add "
                        "--resume to continue it, or --force to start over"
                    )
                shutil.rmtree(self.partial)
            if self.partial.exists():
                self._pick_up()
            else:
                self.partial.mkdir()
                (self.partial / "depth").mkdir()
                (self.partial / "intensity").mkdir()
                (self.partial / "resume").mkdir()
                self._save_manifest()
        self._open = True

    def _pick_up(self) -> None:
        data = _read_manifest(self.partial)
        if data is None:
            raise InputFileError(
                self.partial,
                f"no {MANIFEST_NAME}: not an unfinished fuse4d run; remove it or use --force",
            )
        diff = _identity_diff(self.identity, data.get("identity") or {})
        if diff:
            raise ParameterError(
                f"{self.partial}: cannot resume: the {', '.join(diff)} differ from the "
                "unfinished run's; rerun with the same input and options, or use --force "
                "to start over"
            )
        done = data.get("frames_done")
        checkpoint = data.get("checkpoint")
        if not isinstance(done, int) or not 0 <= done <= self.identity["frames"]:
            raise InputFileError(self.partial / MANIFEST_NAME, f"bad frames_done {done!r}")
        self.frames_done = done
        seconds = data.get("seconds")
        self._seconds_before = float(seconds) if isinstance(seconds, int | float) else 0.0
        self._has_mask = data.get("has_mask")
        self._checkpoint = checkpoint if isinstance(checkpoint, dict) else None
        if done == self.identity["frames"]:
            # every frame on disk (a kill inside close, which removes resume/): nothing is
            # fused again (without a checkpoint every frame was), and the seed is not needed
            # (its absence failed every resume)
            self._checkpoint = None
            self.restart_frame = done
        elif self._checkpoint is not None:
            self.restart_frame = int(self._checkpoint["frame"])
            seed = self._checkpoint.get("seed")
            if seed is not None:
                # fixed names only: the manifest never points outside the folder
                seed_path = self.partial / "resume" / f"seed-{self.restart_frame:06d}.npy"
                if not seed_path.is_file():
                    raise InputFileError(
                        seed_path,
                        "the checkpoint's warm-start flow is missing; use --force to start over",
                    )
                self.seed = np.load(seed_path, allow_pickle=False)
        self._clean()

    def _clean(self) -> None:
        """Drop temporaries of a hard kill and frames past ``frames_done``."""
        for sub in ("depth", "intensity", "mask", "resume"):
            folder = self.partial / sub
            if not folder.is_dir():
                continue
            keep = f"seed-{self.restart_frame:06d}.npy"
            for p in folder.iterdir():
                stem = p.stem
                stale = p.name.startswith(".")
                stale |= sub != "resume" and stem.isdigit() and int(stem) >= self.frames_done
                stale |= sub == "resume" and p.name.startswith("seed-") and p.name != keep
                if stale:
                    p.unlink()
        for p in self.partial.glob(".*.tmp-*"):
            p.unlink()
        stamps = self.partial / "resume" / "timestamps.txt"
        if stamps.exists():
            lines = stamps.read_text().splitlines()[: self.frames_done]
            stamps.write_text("".join(line + "\n" for line in lines))

    def _save_manifest(self, *, complete: bool = False, folder: Path | None = None) -> None:
        _write_json_atomic(
            (folder or self.partial) / MANIFEST_NAME,
            {
                "format": _FORMAT,
                "tool": "fuse4d run",
                "complete": complete,
                "frames_done": self.frames_done,
                "seconds": self._seconds_before
                + (0.0 if self._opened_at is None else time.perf_counter() - self._opened_at),
                "steady_ms_per_frame": self._steady_ms,
                "has_mask": self._has_mask,
                "checkpoint": self._checkpoint,
                "identity": self.identity,
                "updated": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
            },
        )

    # ------------------------------------------------------------------ frames
    def write(
        self,
        depth: np.ndarray,
        intensity: np.ndarray,
        *,
        mask: np.ndarray | None = None,
        timestamp: float | None = None,
        source: np.ndarray | None = None,
        confidence: np.ndarray | None = None,
    ) -> None:
        """Write frame :attr:`frames_done` and count it as done (one manifest update); the
        arguments as :meth:`fuse4d.io.FrameFolderWriter.write`."""
        if not self._open:
            raise RuntimeError("ResumableFolderWriter is not open; use it in a `with` block")
        k = self.frames_done
        with write_errors(self.partial):
            if self._has_mask is None:
                self._has_mask = mask is not None
            if self._has_mask != (mask is not None):
                raise ParameterError(f"frame {k}: give a mask for every frame or for none")
            name = f"{k:06d}.png"
            units = depth_to_units(depth, self.depth_unit_mm, self._report)
            self._png(units, "depth", name)
            self._png(intensity_image(intensity, None), "intensity", name)
            if mask is not None:
                (self.partial / "mask").mkdir(exist_ok=True)
                self._png(np.where(np.asarray(mask, bool), 255, 0).astype(np.uint8), "mask", name)
            check_flags(k, self.intrinsics.shape, source, confidence)
            if source is not None:
                for sub, image in flag_images(source, confidence):
                    (self.partial / sub).mkdir(exist_ok=True)
                    self._png(image, sub, name)
            stamp = "nan" if timestamp is None else f"{float(timestamp):.6f}"
            with (self.partial / "resume" / "timestamps.txt").open("a") as f:
                f.write(stamp + "\n")
            self.frames_done = k + 1
            self._save_manifest()

    def _png(self, image: np.ndarray, sub: str, name: str) -> None:
        _write_atomic(self.partial / sub / name, lambda tmp: encode_png(image, tmp))

    def wants_checkpoint(self) -> bool:
        """True when the caller should call :meth:`checkpoint` after the last write."""
        return self.frames_done % self.checkpoint_every == 0

    def checkpoint(self, seed: np.ndarray | None) -> None:
        """Record that output can restart at :attr:`frames_done` with warm start ``seed``."""
        frame = self.frames_done
        with write_errors(self.partial):
            folder = self.partial / "resume"
            if seed is not None:
                target = folder / f"seed-{frame:06d}.npy"
                _write_atomic(target, lambda tmp: _save_npy(tmp, seed))
            previous = self._checkpoint
            self._checkpoint = {"frame": frame, "seed": None if seed is None else "stored"}
            self._save_manifest()
            if previous is not None and previous.get("frame") != frame:
                (folder / f"seed-{int(previous['frame']):06d}.npy").unlink(missing_ok=True)

    def close(self) -> None:
        """All frames written: write ``camera.json``, ``timestamps.txt``, move into place."""
        if not self._open:
            return
        self._open = False
        if self.frames_done != self.identity["frames"]:
            raise RuntimeError(
                f"{self.path}: {self.frames_done} of {self.identity['frames']} frames written"
            )
        with write_errors(self.partial):
            (self.partial / "camera.json").write_text(
                camera_json_text(self.intrinsics, self.depth_unit_mm, self.fps, self.sensor)
            )
            stamps_file = self.partial / "resume" / "timestamps.txt"
            stamps = stamps_file.read_text().split() if stamps_file.exists() else []
            if stamps and all(s != "nan" for s in stamps):
                (self.partial / "timestamps.txt").write_text("".join(s + "\n" for s in stamps))
            self._checkpoint = None
            self._save_manifest()  # no checkpoint names resume/ once it is gone
            if (self.partial / "resume").is_dir():  # gone after a kill just past this line
                shutil.rmtree(self.partial / "resume")
            self._save_manifest(complete=True)
            if self.path.exists():
                _replace_existing(self.partial, self.path)
            else:
                self.partial.replace(self.path)
        self._report.warn(str(self.path))
