"""zarr v3 output of the dask engine: one shard per time chunk, region writes, done markers.

Layout of ``OUT.zarr`` (a zarr v3 group)::

    depth    (T, H, W) float32, mm, NaN = invalid   dims ("t", "y", "x")
    support  (T, H, W) uint8, frames                 temporal support
    filled   (T, H, W) bool                          filled by Eq. 6
    source   (T, H, W) uint8                         where each value comes from
                                                     (``fuse4d.FusedFrame.source`` codes)
    confidence (T, H, W) float32                     fraction of the window that measured it
    flow_forward, flow_backward  (T-1, H, W, 2) float32 px   only with ``save_flows``

Group attributes: ``intrinsics`` (fx, fy, cx, cy, width, height in px), ``units``, and
``fuse4d`` (version, parameters, flow, chunking, source, ``complete``). Every array has one
shard per time chunk (inner chunks of one frame, so a reader can fetch single frames), so the
tasks of different chunks never write the same file; Blosc LZ4 + byte-shuffle compression (:func:`fuse4d.io.zarrstore.codec`).

While running, the store lives at ``OUT.zarr.partial`` with one marker file per finished chunk
in ``OUT.zarr.partial/.fuse4d-done/`` (written after the chunk's data). At the end the markers
are removed, ``complete`` is set and the folder is renamed to ``OUT.zarr`` — the output appears
atomically. ``resume=True`` reopens ``OUT.zarr.partial`` (after checking that the parameters and
the input are the same) and skips the chunks that have a marker.
"""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import dask
import numpy as np
import zarr
from numpy.typing import NDArray

from .._version import __version__
from ..camera import Intrinsics
from ..errors import OutputExistsError, ParameterError
from ..io import check_output
from ..io._atomic import reports_write_errors, write_errors
from ..io.zarrstore import codec
from .graph import DaskFusion, chunk_bounds, delayed_blocks

__all__ = ["ZarrOutput", "write_chunk", "write_zarr"]

_ARRAYS = {
    "depth": (np.float32, float("nan"), "mm"),
    "support": (np.uint8, 0, "frames"),
    "filled": (np.bool_, False, ""),
    "source": (np.uint8, 0, ""),
    "confidence": (np.float32, 0.0, ""),
}
_MARKERS = ".fuse4d-done"
_SCRATCH = ".fuse4d-flows"


def _remove(path: Path) -> None:
    """Delete a replaced output or a stale staging store: a folder, or a file or link (of
    that name; rmtree refused it, "Not a directory")."""
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    else:
        path.unlink()


def _marker(staging: Path, k: int) -> Path:
    return staging / _MARKERS / f"chunk-{k:06d}"


def _output_of(staging: str | Path) -> Path:
    """The output ``OUT.zarr`` whose staging folder is ``staging`` (``OUT.zarr.partial``):
    what a write error in a task names."""
    staging = Path(staging)
    return staging.with_name(staging.name.removesuffix(".partial"))


def write_chunk(
    staging: str,
    k: int,
    start: int,
    depth: NDArray[np.float32],
    support: NDArray[np.uint8],
    filled: NDArray[np.bool_],
    forward: NDArray[np.float32] | None = None,
    backward: NDArray[np.float32] | None = None,
    source: NDArray[np.uint8] | None = None,
    confidence: NDArray[np.float32] | None = None,
) -> int:
    """Write time chunk ``k`` (frames ``[start, start + len(depth))``, and the pairs starting
    there when flows are saved) into the store at ``staging``, then its done marker; runs on a
    worker. Returns ``k``.

    Raises
    ------
    OutputWriteError
        A full disk, a read-only folder, ... (naming ``OUT.zarr``).
    """
    with write_errors(_output_of(staging)):
        root = zarr.open_group(staging, mode="r+")
        stop = start + depth.shape[0]
        blocks = [("depth", depth), ("support", support), ("filled", filled)]
        if source is not None and confidence is not None:
            blocks += [("source", source), ("confidence", confidence)]
        if forward is not None and backward is not None and len(forward):
            blocks += [("flow_forward", forward), ("flow_backward", backward)]
        for name, block in blocks:
            root[name][start : start + block.shape[0]] = block  # type: ignore[index]
        marker = _marker(Path(staging), k)
        marker.parent.mkdir(exist_ok=True)
        tmp = marker.with_suffix(".tmp")
        tmp.write_text(json.dumps({"start": start, "stop": stop}))
        tmp.replace(marker)
        return k


class ZarrOutput:
    """A zarr v3 fusion output being written (see the module docstring for the layout).

    Parameters
    ----------
    path : str or Path
        Final location (``OUT.zarr``).
    shape : (T, H, W)
        Output size, frames and px.
    chunk_frames : int
        Frames per time chunk (= per shard, = per task).
    intrinsics : Intrinsics
    metadata : dict
        JSON-friendly run description (parameters, flow, source); stored under
        ``attrs["fuse4d"]`` and compared on resume.
    resume : bool
        Reopen an interrupted run's ``OUT.zarr.partial`` instead of refusing it.
    save_flows : bool
        Also store the pair flows (``flow_forward``, ``flow_backward``: ``(T-1, H, W, 2)``
        float32 px, dims ``("t", "y", "x", "uv")``, pair t in the shard of frame t).
    overwrite : bool
        Replace an existing ``OUT.zarr`` (at the end, not before) and discard a stale
        ``OUT.zarr.partial``.
    defer : bool
        Only check now; :meth:`prepare` writes the staging store later (so that a caller with
        several outputs writes none before all are checked). Default: prepare now.

    Raises
    ------
    OutputExistsError
        If ``OUT.zarr`` exists (and neither ``overwrite`` nor a complete ``resume``), or a
        partial run exists without ``resume``/``overwrite``.
    ParameterError
        If the output folder does not exist, if ``overwrite`` would replace a folder that
        fuse4d did not write (:func:`fuse4d.io.check_output`), or ``resume`` finds a partial
        run of other parameters or another input (a ValueError).
    """

    def __init__(
        self,
        path: str | Path,
        *,
        shape: tuple[int, int, int],
        chunk_frames: int,
        intrinsics: Intrinsics,
        metadata: dict[str, Any],
        resume: bool = False,
        overwrite: bool = False,
        save_flows: bool = False,
        defer: bool = False,
    ) -> None:
        # absolute: the tasks get these paths, and a cluster's workers run in another folder
        self.path = Path(path).absolute()
        self.save_flows = bool(save_flows) and shape[0] > 1
        self.staging = self.path.with_name(self.path.name + ".partial")
        self.shape = tuple(int(v) for v in shape)
        self.chunk_frames = int(chunk_frames)
        self.bounds = chunk_bounds(self.shape[0], self.chunk_frames)
        self.overwrite = overwrite
        self.metadata = {
            **metadata,
            "version": __version__,
            "shape": list(self.shape),
            "chunk_frames": self.chunk_frames,
            "flows_saved": self.save_flows,
        }
        self._intrinsics = intrinsics
        self._discard = False  # a stale staging store to remove before creating a new one
        self._resumed = False
        self._prepared = False
        if not self.path.parent.is_dir():
            raise ParameterError(f"{self.path}: output folder {self.path.parent} does not exist")
        if overwrite:  # a folder (or staging folder) of the user's own files is never replaced
            check_output(self.path, overwrite=True)
            check_output(self.staging, overwrite=True)
        self.already_complete = False
        if self.path.exists() and not overwrite:
            if resume and self._is_complete(self.path):
                self.already_complete = True
                return
            raise OutputExistsError(self.path)
        if self.staging.exists():
            if resume:
                self._check_resumable()
                self._resumed = True
                return
            if not overwrite:
                raise OutputExistsError(
                    f"{self.staging} (an interrupted run: pass --resume to continue it, "
                    "--force to start over)"
                )
            self._discard = True
        if not defer:
            self.prepare()

    @reports_write_errors
    def prepare(self) -> None:
        """Write the staging store ``OUT.zarr.partial`` (discarding a stale one with
        ``overwrite``); the constructor does this unless ``defer``. Nothing to do where the
        output is complete or a partial run is resumed, or on a second call.

        Raises
        ------
        OutputWriteError
            A read-only folder, a full disk, ... (naming ``OUT.zarr``).
        """
        if self.already_complete or self._resumed or self._prepared:
            return
        if self._discard:
            _remove(self.staging)
        self._create(self._intrinsics)
        self._prepared = True

    # ------------------------------------------------------------------ setup
    def _create(self, k: Intrinsics) -> None:
        t, h, w = self.shape
        root = zarr.open_group(
            str(self.staging),
            mode="w-",
            zarr_format=3,
            attributes={
                "intrinsics": {
                    "fx": k.fx,
                    "fy": k.fy,
                    "cx": k.cx,
                    "cy": k.cy,
                    "width": k.width,
                    "height": k.height,
                    "unit": "px",
                },
                "units": {"depth": "mm", "support": "frames", "t": "frame", "y": "px", "x": "px"},
                "fuse4d": {**self.metadata, "complete": False},
            },
        )
        for name, (dtype, fill, unit) in _ARRAYS.items():
            root.create_array(
                name,
                shape=(t, h, w),
                dtype=dtype,
                chunks=(1, h, w),
                shards=(self.chunk_frames, h, w),
                fill_value=fill,
                compressors=codec(),
                dimension_names=("t", "y", "x"),
                attributes={"unit": unit} if unit else {},
            )
        if self.save_flows:
            for name, grid in (("flow_forward", "frame t"), ("flow_backward", "frame t+1")):
                root.create_array(
                    name,
                    shape=(t - 1, h, w, 2),
                    dtype=np.float32,
                    chunks=(1, h, w, 2),
                    shards=(self.chunk_frames, h, w, 2),
                    fill_value=0.0,
                    compressors=codec(),
                    dimension_names=("t", "y", "x", "uv"),
                    attributes={"unit": "px", "grid": grid, "components": ["du", "dv"]},
                )
        (self.staging / _MARKERS).mkdir()

    def _comparable(self, meta: dict[str, Any]) -> dict[str, Any]:
        """``meta`` less what a resumed or finished run may differ in: ``complete``, and the
        input's path (``source.path``; a moved input is the same input, its fingerprint
        says whether its files changed)."""
        out = {k: v for k, v in meta.items() if k != "complete"}
        if isinstance(out.get("source"), dict):
            out["source"] = {k: v for k, v in out["source"].items() if k != "path"}
        return out

    def _is_complete(self, path: Path) -> bool:
        try:
            meta = dict(zarr.open_group(str(path), mode="r").attrs.get("fuse4d", {}))
        except (FileNotFoundError, ValueError, KeyError, zarr.errors.GroupNotFoundError):
            return False
        return bool(meta.get("complete")) and self._comparable(meta) == self._comparable(
            json.loads(json.dumps(self.metadata))
        )

    def _check_resumable(self) -> None:
        meta = dict(zarr.open_group(str(self.staging), mode="r").attrs.get("fuse4d", {}))
        want = self._comparable(json.loads(json.dumps(self.metadata)))
        have = self._comparable(meta)
        if have != want:
            diff = sorted(k for k in set(want) | set(have) if want.get(k) != have.get(k))
            raise ParameterError(
                f"{self.staging}: cannot resume, the interrupted run differs in {diff}; "
                "rerun with the same input and parameters, or --force to start over"
            )

    # ------------------------------------------------------------------ writing
    def done_chunks(self) -> set[int]:
        """Indices of the time chunks already written (all of them when complete)."""
        if self.already_complete:
            return set(range(len(self.bounds)))
        folder = self.staging / _MARKERS
        if not folder.is_dir():
            # killed inside finalize (marked complete, markers removed, not yet renamed): the
            # resume recomputed every chunk and then failed writing into the missing folder
            return set(range(len(self.bounds))) if self._staging_complete() else set()
        return {int(p.name.split("-")[1]) for p in folder.glob("chunk-*") if p.suffix == ""}

    def _staging_complete(self) -> bool:
        """Whether the staging store is already marked complete (a finalize cut short)."""
        try:
            meta = dict(zarr.open_group(str(self.staging), mode="r").attrs).get("fuse4d")
        except (OSError, ValueError, LookupError):
            return False
        return isinstance(meta, dict) and meta.get("complete") is True

    def tasks(self, result: DaskFusion) -> list[Any]:
        """One delayed write per unfinished time chunk of ``result``."""
        if tuple(result.depth.shape) != self.shape:
            raise ValueError(f"result shape {result.depth.shape} != output shape {self.shape}")
        c = self.chunk_frames
        depth, support, filled, source, confidence = (
            delayed_blocks(a.rechunk({0: c}))
            for a in (
                result.depth,
                result.support,
                result.filled,
                result.source,
                result.confidence,
            )
        )
        pairs: list[Any] = [None] * len(self.bounds)
        forward, backward = pairs, pairs
        if self.save_flows:  # pair chunk k = the pairs starting in time chunk k
            forward = delayed_blocks(result.flows.forward.rechunk({0: c}))
            backward = delayed_blocks(result.flows.backward.rechunk({0: c}))
            forward += [None] * (len(self.bounds) - len(forward))
            backward += [None] * (len(self.bounds) - len(backward))
        done = self.done_chunks()
        write = dask.delayed(write_chunk, pure=False)
        return [
            write(
                str(self.staging),
                k,
                s,
                depth[k],
                support[k],
                filled[k],
                forward[k],
                backward[k],
                source[k],
                confidence[k],
            )
            for k, (s, _) in enumerate(self.bounds)
            if k not in done
        ]

    @reports_write_errors
    def finalize(self) -> Path:
        """Check every chunk is written, mark complete and move into place; return the path.

        Raises
        ------
        OutputWriteError
            A read-only folder, a full disk, ... (naming ``OUT.zarr``).
        """
        if self.already_complete:
            return self.path
        missing = sorted(set(range(len(self.bounds))) - self.done_chunks())
        if missing:
            raise RuntimeError(f"{self.staging}: chunks {missing} were not written")
        root = zarr.open_group(str(self.staging), mode="r+")
        root.attrs["fuse4d"] = {**json.loads(json.dumps(self.metadata)), "complete": True}
        shutil.rmtree(self.staging / _MARKERS, ignore_errors=True)  # gone if killed after this
        if (self.staging / _SCRATCH).is_dir():  # pair flows of fuse4d.scale.streamed
            shutil.rmtree(self.staging / _SCRATCH)
        if self.path.exists():  # overwrite: replace only now that the new output is complete
            old = self.path.with_name(f".{self.path.name}.old-{os.getpid()}")
            self.path.rename(old)
            self.staging.rename(self.path)
            _remove(old)
        else:
            self.staging.rename(self.path)
        return self.path


def write_zarr(
    result: DaskFusion,
    path: str | Path,
    *,
    intrinsics: Intrinsics,
    metadata: dict[str, Any] | None = None,
    resume: bool = False,
    overwrite: bool = False,
    save_flows: bool = False,
    compute: Callable[..., Any] | None = None,
) -> Path:
    """Compute ``result`` chunk by chunk into a zarr v3 store (see the module docstring).

    Parameters
    ----------
    result : DaskFusion
        From :func:`fuse4d.dask.fuse`.
    path : str or Path
        ``OUT.zarr``.
    intrinsics : Intrinsics
        Stored as attributes.
    metadata : dict, optional
        Extra JSON-friendly description (the fusion parameters are always stored).
    resume, overwrite : bool
        See :class:`ZarrOutput`.
    save_flows : bool
        Also store the pair flows the fusion used (``flow_forward``/``flow_backward``,
        ``(T-1, H, W, 2)`` px): scene-flow export, or ``flow=`` of later runs (parameter
        sweeps) without recomputing them.
    compute : callable, optional
        ``compute(*delayed)`` that runs the write tasks (default :func:`dask.compute`, i.e.
        the active client or the threaded scheduler).

    Returns
    -------
    Path
        The finished output.
    """
    meta = {"params": result.params.to_dict(), "flow": result.flows.method, **(metadata or {})}
    out = ZarrOutput(
        path,
        shape=tuple(result.depth.shape),
        chunk_frames=result.chunk_frames,
        intrinsics=intrinsics,
        metadata=meta,
        resume=resume,
        overwrite=overwrite,
        save_flows=save_flows,
    )
    tasks = out.tasks(result)
    if tasks:
        (compute or dask.compute)(*tasks)
    return out.finalize()
