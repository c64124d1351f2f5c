"""Exception types of fuse4d.

All of them subclass :class:`ValueError` (bad values) or :class:`OSError` (files), so callers
that catch the built-in types keep working. The CLI turns any of them into a one-line message
and a non-zero exit code.
"""

from __future__ import annotations

from os import PathLike

__all__ = ["InputFileError", "OutputExistsError", "ShapeError"]


class ShapeError(ValueError):
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


class InputFileError(ValueError):
    """An input file is missing, corrupt or inconsistent.

    The message always names the file and, where it applies, the frame index, so that a
    user can find the culprit in a folder of thousands of frames.

    Parameters
    ----------
    path : str or PathLike
        The offending file (or folder).
    problem : str
        What is wrong, in plain words.
    frame : int, optional
        0-based frame index, if the file belongs to a sequence.
    """

    def __init__(self, path: str | PathLike[str], problem: str, *, frame: int | None = None):
        self.path = str(path)
        self.frame = frame
        self.problem = problem
        where = self.path if frame is None else f"{self.path} (frame {frame})"
        super().__init__(f"{where}: {problem}")


class OutputExistsError(FileExistsError):
    """An output file exists and overwriting was not requested."""

    def __init__(self, path: str | PathLike[str]) -> None:
        self.path = str(path)
        super().__init__(
            f"{self.path}: output exists; pass overwrite=True (CLI: --force) to replace it"
        )
