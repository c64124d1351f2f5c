"""Exception types of fuse4d: the error contract of the API and the CLI.

Every problem caused by the user's input, parameters or environment (a corrupt file, a bad
option value, a full disk) raises a subclass of :class:`Fuse4dError` whose message names the
file, frame or field and says what to do. Anything else escaping fuse4d is a bug.

The classes also subclass the matching built-in type (:class:`ValueError` for bad values,
:class:`OSError` for files), so callers that catch the built-in types keep working; an
:class:`InputFileError` for a missing file is an :class:`InputNotFoundError`, which is a
:class:`FileNotFoundError` as well.

The CLI prints a :class:`Fuse4dError` as one ``fuse4d: error: ...`` line and exits with 2;
any other exception is reported as a bug (exit 70) with the path of a crash report.
"""

from __future__ import annotations

from os import PathLike
from typing import Any, Self

__all__ = [
    "CameraError",
    "Fuse4dError",
    "InputFileError",
    "InputNotFoundError",
    "OutputExistsError",
    "OutputWriteError",
    "ParameterError",
    "ParameterTypeError",
    "ShapeError",
]

#: Problems of an :class:`InputFileError` that mean "does not exist".
_MISSING = ("file not found", "folder not found", "file or folder not found",
            "configuration file not found")  # fmt: skip


class Fuse4dError(Exception):
    """Base of every error fuse4d raises for bad input, parameters or environment.

    Never raised for an internal bug. The CLI turns it into one line on stderr, exit code 2.
    """


class ParameterError(Fuse4dError, ValueError):
    """A parameter (API argument, CLI option, configuration value) has a bad value.

    The message names the parameter and the accepted values.
    """


class ParameterTypeError(ParameterError, TypeError):
    """A parameter value of the wrong type (a word where a number is needed, ...)."""


class ShapeError(Fuse4dError, ValueError):
    """An array has the wrong shape.

    Parameters
    ----------
    name : str
        Name of the offending parameter.
    expected : tuple
        Expected shape, with symbolic dimensions as strings (``("T", "H", "W")``).
    actual : tuple of int
        The shape received.
    hint : str, optional
        How to fix it.
    """

    def __init__(
        self, name: str, expected: tuple[object, ...], actual: tuple[int, ...], hint: str = ""
    ) -> None:
        self.name = name
        self.expected_shape = tuple(expected)
        self.actual_shape = tuple(actual)
        exp = "(" + ", ".join(str(e) for e in expected) + ")"
        msg = f"{name} must have shape {exp}, got {tuple(actual)}"
        if hint:
            msg += f". {hint}"
        super().__init__(msg)

    def __reduce__(self) -> tuple[Any, ...]:
        return (_rebuild_shape_error, (self.name, self.expected_shape, self.actual_shape,
                                       str(self)))  # fmt: skip


def _rebuild_shape_error(name: str, expected: tuple, actual: tuple, message: str) -> ShapeError:
    err = ShapeError(name, expected, actual)
    err.args = (message,)
    return err


class InputFileError(Fuse4dError, ValueError):
    """An input file is missing, corrupt or inconsistent.

    The message always names the file and, where it applies, the frame index, so that a
    user can find the culprit in a folder of thousands of frames. When ``problem`` says the
    file or folder does not exist, the instance is an :class:`InputNotFoundError` (also a
    :class:`FileNotFoundError`).

    Parameters
    ----------
    path : str or PathLike
        The offending file (or folder).
    problem : str
        What is wrong, in plain words.
    frame : int, optional
        0-based frame index, if the file belongs to a sequence.
    """

    def __new__(cls, path: str | PathLike[str], problem: str, *, frame: int | None = None) -> Self:
        kind: Any = cls
        if cls is InputFileError and problem.startswith(_MISSING):
            kind = InputNotFoundError
        # OSError's layout differs from ValueError's: allocate with the right base, no args
        # (the message is set by __init__).
        base: Any = OSError if issubclass(kind, OSError) else ValueError
        return base.__new__(kind)

    def __init__(
        self, path: str | PathLike[str], problem: str, *, frame: int | None = None
    ) -> None:
        self.path = str(path)
        self.frame = frame
        self.problem = problem
        where = self.path if frame is None else f"{self.path} (frame {frame})"
        super().__init__(f"{where}: {problem}")

    def __reduce__(self) -> tuple[Any, ...]:
        return (_rebuild_input_error, (type(self), self.path, self.problem, self.frame))


def _rebuild_input_error(
    cls: type[InputFileError], path: str, problem: str, frame: int | None
) -> InputFileError:
    return cls(path, problem, frame=frame)


class InputNotFoundError(InputFileError, FileNotFoundError):
    """An input file or folder does not exist (an :class:`InputFileError` and a
    :class:`FileNotFoundError`)."""


class CameraError(Fuse4dError, OSError):
    """A camera could not be started or stopped delivering frames (disconnected, a mode it
    cannot stream, a timeout). The message names the camera and what it was asked for."""


class OutputExistsError(Fuse4dError, FileExistsError):
    """An output file exists and overwriting was not requested."""

    def __init__(self, path: str | PathLike[str]) -> None:
        self.path = str(path)
        super().__init__(
            f"{self.path}: output exists; pass overwrite=True (CLI: --force) to replace it"
        )

    def __reduce__(self) -> tuple[Any, ...]:
        return (OutputExistsError, (self.path,))


class OutputWriteError(Fuse4dError, OSError):
    """An output could not be written (disk full, read-only folder, ...).

    Nothing that looks like a complete output is left behind.

    Parameters
    ----------
    path : str or PathLike
        The output file or folder.
    cause : OSError
        The underlying error (its ``strerror`` goes into the message).
    """

    def __init__(self, path: str | PathLike[str], cause: OSError) -> None:
        self.path = str(path)
        self.cause_errno = cause.errno
        reason = cause.strerror or str(cause) or type(cause).__name__
        hint = _WRITE_HINTS.get(cause.errno or 0, "")
        super().__init__(f"{self.path}: cannot write the output ({reason}){hint}")

    def __reduce__(self) -> tuple[Any, ...]:
        return (_rebuild_write_error, (self.path, self.cause_errno, str(self)))


def _rebuild_write_error(path: str, errno_: int | None, message: str) -> OutputWriteError:
    err = OutputWriteError(path, OSError(errno_, message))
    err.args = (message,)
    return err


def _write_hints() -> dict[int, str]:
    import errno

    return {
        errno.ENOSPC: "; free some disk space or write elsewhere, then run again",
        errno.EDQUOT: "; disk quota exceeded: free some space or write elsewhere",
        errno.EACCES: "; the folder is not writable: choose another output path",
        errno.EPERM: "; the folder is not writable: choose another output path",
        errno.EROFS: "; the file system is read-only: choose another output path",
    }


_WRITE_HINTS = _write_hints()
