"""Atomic output: write to a temporary name in the destination folder, then rename into place.

Every fuse4d writer goes through :func:`atomic_file` (single files) or :func:`atomic_dir`
(frame folders). A reader of the destination therefore sees either the old content (or
nothing) or the complete new content, never a half-written file; on any error the temporary
is removed and the destination is left untouched.
"""

from __future__ import annotations

import errno
import functools
import glob
import os
import re
import secrets
import shutil
import socket
import warnings
import zlib
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from os import PathLike
from pathlib import Path
from typing import TYPE_CHECKING, Any, Concatenate, ParamSpec, Self, TypeVar

from ..errors import OutputExistsError, OutputWriteError, ParameterError

if TYPE_CHECKING:
    from ..sequence import GroundTruth

__all__ = ["atomic_dir", "atomic_file", "check_output", "write_errors"]


def check_not_an_input(path: str | PathLike[str], inputs: Iterable[str | PathLike[str]]) -> None:
    """Refuse an output ``path`` that is one of ``inputs``, lies inside an input folder or
    holds one (ParameterError): writing it would replace the recording being read."""
    out = Path(path)
    resolved = out.resolve()
    for inp in inputs:
        src = Path(inp).resolve()
        if resolved == src or src in resolved.parents or resolved in src.parents:
            raise ParameterError(
                f"{out}: output would overwrite the input {inp}; choose another path"
            )


def check_output(
    path: str | PathLike[str],
    *,
    overwrite: bool = False,
    inputs: Iterable[str | PathLike[str]] = (),
    probe: bool = True,
) -> Path:
    """Validate an output path before anything is written.

    Parameters
    ----------
    path : str or PathLike
        The output file or folder.
    overwrite : bool, optional
        Allow replacing an existing output. Default False.
    inputs : iterable of path, optional
        Paths the caller reads from; writing onto any of them (or into a folder input) is
        refused even with ``overwrite=True``.
    probe : bool, optional
        Try the folder now (a file created and removed: a read-only folder fails before any
        work; default True), and remove the temporaries a killed fuse4d process left for this
        output (:func:`_sweep_dead_temporaries`). False where nothing may be written (a
        ``--resume`` of a finished run) or the caller creates its temporary at once.

    Returns
    -------
    Path
        The output path.

    Raises
    ------
    OutputExistsError
        If ``path`` exists and ``overwrite`` is False.
    OutputWriteError
        ``probe`` and the folder takes no new files (read-only, full, not ours).
    ValueError
        If ``path`` is one of ``inputs`` or lies inside an input folder, if its parent folder
        does not exist or is not a folder, or if ``overwrite`` would replace a non-empty
        folder that is not a fuse4d output (no :data:`OUTPUT_MARKERS` file in it).
    """
    out = Path(path)
    resolved = out.resolve()
    check_not_an_input(out, inputs)
    if not resolved.parent.is_dir():
        if resolved.parent.exists():  # e.g. mk.py/x.npz with mk.py a file
            raise ParameterError(f"{out}: {out.parent} is not a folder")
        raise ParameterError(f"{out}: output folder {out.parent} does not exist")
    if out.exists() and not overwrite:
        raise OutputExistsError(out)
    if overwrite and out.is_dir() and not out.is_symlink():
        _check_replaceable_folder(out)
    if probe:
        # a folder that takes no new files (read-only, full, not ours) fails now, before the
        # work: a run wrote its output, then failed on its --report folder (rerun: "exists")
        _sweep_dead_temporaries(out)
        _create_temp(out, directory=False).unlink(missing_ok=True)
    return out


#: Files of which one marks a folder as an output fuse4d writes (frame folder, zarr store,
#: report, demo, resumable run): only such a folder is replaced with ``overwrite``.
OUTPUT_MARKERS = ("camera.json", "zarr.json", "report.html", "metrics.json", "fuse4d-run.json")


def _check_replaceable_folder(out: Path) -> None:
    """Refuse to replace a non-empty folder that holds no :data:`OUTPUT_MARKERS` file: a
    mistyped ``-o ~/data --force`` deleted a folder of the user's own files."""
    try:
        entries = sorted(p.name for p in out.iterdir())
    except OSError:
        return  # not readable: the write fails later, naming the output
    if entries and not any(name in entries for name in OUTPUT_MARKERS):
        shown = ", ".join(entries[:3]) + (", ..." if len(entries) > 3 else "")
        raise ParameterError(
            f"{out}: not replaced: the folder holds files that fuse4d did not write ({shown}); "
            "remove it yourself or choose another output"
        )


#: errno values that mean "the output cannot be written here" (not a bug, not the input).
_WRITE_ERRNOS = frozenset(
    {errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM, errno.EFBIG, errno.EIO}
)


@contextmanager
def write_errors(path: str | PathLike[str]) -> Iterator[None]:
    """Report a full disk, a read-only folder, ... while writing ``path`` as
    :class:`~fuse4d.OutputWriteError` (a one-line user error naming the output)."""
    try:
        yield
    except OutputWriteError:
        raise
    except OSError as exc:
        if exc.errno in _WRITE_ERRNOS:
            raise OutputWriteError(path, exc) from exc
        raise


_P = ParamSpec("_P")
_R = TypeVar("_R")
_W = TypeVar("_W")


def reports_write_errors(
    method: Callable[Concatenate[_W, _P], _R],
) -> Callable[Concatenate[_W, _P], _R]:
    """Decorate a streaming writer's method (``open``, ``write``, ``close``) so that a full
    disk, a read-only folder, ... while it runs raises :class:`~fuse4d.OutputWriteError` naming
    the output ``self.path``, not the bare ``OSError`` naming the temporary (the atomic context
    sees only the synthetic exception of ``abort``)."""

    @functools.wraps(method)
    def wrapper(self: _W, *args: _P.args, **kwargs: _P.kwargs) -> _R:
        with write_errors(self.path):  # type: ignore[attr-defined]
            return method(self, *args, **kwargs)

    return wrapper


#: A staged temporary or a replaced folder's old copy: ``.NAME.tmp-HOST-PID-HEX`` /
#: ``.NAME.old-HOST-PID-HEX`` next to the output NAME; HOST (8 hex digits of the host name's
#: hash) and PID name the writing process.
_STAGED = re.compile(
    r"^\.(?P<name>.+)\.(?:tmp|old)-(?P<host>[0-9a-f]{8})-(?P<pid>\d+)-[0-9a-f]{8}$"
)


def _host_tag() -> str:
    return f"{zlib.crc32(socket.gethostname().encode()):08x}"


def _staged_name(dest: Path, kind: str) -> Path:
    tag = f"{_host_tag()}-{os.getpid()}-{secrets.token_hex(4)}"
    return dest.parent / f".{dest.name}.{kind}-{tag}"


def _process_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # EPERM: alive, another user's
        return True
    return True


def _sweep_dead_temporaries(dest: Path) -> None:
    """Delete the temporaries and old copies of ``dest`` that a killed fuse4d process left
    (``SIGKILL``, a power cut: no cleanup ran): those written on this host whose process no
    longer exists. Kept: those of a live process, of another host (a shared folder), names
    without host and process, and an old copy while ``dest`` is missing (a kill between the
    two renames of :func:`_replace_existing` left the previous output only there). Best
    effort: one that cannot be removed (another user's) stays. Once per output
    (:func:`check_output`), never per file written into it."""
    try:
        candidates = list(dest.parent.glob(f".{glob.escape(dest.name)}.*-*"))
    except OSError:
        return
    host = _host_tag()
    for path in candidates:
        m = _STAGED.match(path.name)
        if m is None or m["name"] != dest.name or m["host"] != host:
            continue
        if _process_alive(int(m["pid"])):
            continue
        if ".old-" in path.name[len(dest.name) + 1 :] and not dest.exists():
            continue
        try:
            if path.is_dir() and not path.is_symlink():
                shutil.rmtree(path, ignore_errors=True)
            else:
                path.unlink(missing_ok=True)
        except OSError:
            pass


def _create_temp(dest: Path, *, directory: bool) -> Path:
    """A new, empty file or folder ``.NAME.tmp-HOST-PID-XXXXXXXX`` next to ``dest``.

    Created with the modes of an ordinary new file or folder (0666 / 0777, less the umask,
    which the system applies), so the output needs no chmod. ``tempfile.mkstemp`` creates
    0600, and the umask cannot be read without setting it: ``os.umask`` is process-wide, and
    another thread creating a file in between would get the wrong mode.

    Any other failure to create it (the folder exists: ``check_output``) means the folder
    takes no new files (e.g. ``/proc``: ENOENT, which named the temporary name): an
    :class:`~fuse4d.OutputWriteError` naming ``dest``.
    """
    for _ in range(100):
        tmp = _staged_name(dest, "tmp")
        try:
            if directory:
                tmp.mkdir(mode=0o777)
            else:
                tmp.touch(mode=0o666, exist_ok=False)  # O_CREAT | O_EXCL
        except FileExistsError:
            continue
        except OSError as exc:
            raise OutputWriteError(dest, exc) from exc
        return tmp
    raise FileExistsError(errno.EEXIST, "no unused temporary name", str(dest.parent))


@contextmanager
def atomic_file(path: str | PathLike[str], *, overwrite: bool = False) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; rename it onto ``path`` on success.

    Raises
    ------
    OutputExistsError
        If ``path`` exists and ``overwrite`` is False (checked before and after writing).
    """
    dest = check_output(path, overwrite=overwrite, probe=False)  # the temporary is the try
    _sweep_dead_temporaries(dest)
    with write_errors(dest):
        tmp = _create_temp(dest, directory=False)
    try:
        with write_errors(dest):
            yield tmp
        if dest.exists() and not overwrite:  # appeared while we were writing
            raise OutputExistsError(dest)
        if dest.is_dir():
            raise ParameterError(f"{dest}: is a folder; cannot replace it with a file")
        tmp.replace(dest)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


@contextmanager
def atomic_dir(path: str | PathLike[str], *, overwrite: bool = False) -> Iterator[Path]:
    """Yield a temporary folder next to ``path``; rename it onto ``path`` on success.

    Notes
    -----
    POSIX cannot atomically replace a non-empty folder. With ``overwrite=True`` an existing
    destination is first renamed aside, the new folder renamed into place, then the old one
    deleted; if the second rename fails the old folder is moved back.
    """
    dest = check_output(path, overwrite=overwrite, probe=False)  # the temporary is the try
    _sweep_dead_temporaries(dest)
    with write_errors(dest):
        tmp = _create_temp(dest, directory=True)
    try:
        with write_errors(dest):
            yield tmp
        if dest.exists():
            if not overwrite:
                raise OutputExistsError(dest)
            _replace_existing(tmp, dest)
        else:
            tmp.replace(dest)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def _replace_existing(tmp: Path, dest: Path) -> None:
    if not dest.is_dir():
        dest.unlink()
        tmp.replace(dest)
        return
    old = _staged_name(dest, "old")
    while old.exists():
        old = _staged_name(dest, "old")
    dest.replace(old)
    try:
        tmp.replace(dest)
    except BaseException:
        old.replace(dest)
        raise
    try:
        shutil.rmtree(old, ignore_errors=True)
    except KeyboardInterrupt:
        # the new output is in place: finish deleting the old copy (a Ctrl-C here left it
        # hidden beside the output for good), then let the interrupt go on
        shutil.rmtree(old, ignore_errors=True)
        raise


class _Abort(Exception):
    """Raised inside an atomic context to make it delete its temporary file or folder."""


class StagedWriter:
    """Context-manager protocol of the writers that stage their output in an atomic file or
    folder (:func:`atomic_file` / :func:`atomic_dir` entered on ``self._stack``): ``with`` calls
    :meth:`open`, then :meth:`close` on success or :meth:`abort` on an exception. Subclasses
    implement ``open``/``close``/``abort``; ``abort`` ends with :meth:`_discard_stage`."""

    _stack: Any = None

    def __enter__(self) -> Self:
        try:
            self.open()
        except BaseException:
            self.abort()  # ``with`` does not call __exit__ when __enter__ fails
            raise
        return self

    def __exit__(self, exc_type: object, exc: object, tb: object) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    def open(self) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def close(self) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def abort(self) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def _discard_stage(self) -> None:
        """Leave the atomic context with an exception, so it deletes the staged output."""
        if self._stack is None:
            return
        stack, self._stack = self._stack, None
        try:
            with stack:
                raise _Abort
        except _Abort:
            pass


def unstored_ground_truth(gt: GroundTruth | None, *, keeps_mask: bool) -> list[str]:
    """The parts of ``gt`` that a layout without ground truth (but the object ``mask`` where
    ``keeps_mask``) drops, as :func:`warn_unstored_ground_truth` names them."""
    if gt is None:
        return []
    parts = [("depth", gt.depth), ("mask", None if keeps_mask else gt.mask), ("flow", gt.flow)]
    dropped = [name for name, value in parts if value is not None]
    dropped += [f"extra[{k!r}]" for k in gt.extra]
    if gt.scene is not None:
        dropped.append("scene")
    return dropped


def checked_for_layout(
    seq: Any,
    path: str | PathLike[str],
    *,
    owner: str,
    layout: str,
    keeps_mask: bool,
    overwrite: bool,
) -> GroundTruth | None:
    """The ground truth of ``seq`` (checked to be a Sequence, for ``owner``) to write as
    ``layout`` to ``path``: the output is checked first (an existing one is refused before
    anything is said about it), then one warning names what the layout drops."""
    from ..sequence import check_sequence

    gt = check_sequence(seq, owner).ground_truth
    dropped = unstored_ground_truth(gt, keeps_mask=keeps_mask)
    check_output(path, overwrite=overwrite)
    warn_unstored_ground_truth(path, layout, dropped, stacklevel=4)
    return gt


def warn_unstored_ground_truth(
    path: str | PathLike[str], layout: str, dropped: list[str], *, stacklevel: int = 3
) -> None:
    """One ``UserWarning``: the ``layout`` output ``path`` does not store the ground truth
    ``dropped`` (nothing when it is empty)."""
    if dropped:
        warnings.warn(
            f"{path}: {layout} does not store ground-truth {', '.join(dropped)}; use .npz to "
            "keep them",
            UserWarning,
            stacklevel=stacklevel,
        )
