"""The reader contract: a fuse4d error or a valid result, never anything else.

"Anything else" is another exception, a hang (> :data:`TIME_LIMIT_S`) or a memory blow-up
(> :data:`MEMORY_LIMIT_BYTES` above the process's size when the call started: the address
space is capped for the duration of the call, so a huge allocation fails fast with
``MemoryError`` instead of taking the machine down).
"""

from __future__ import annotations

import gc
import math
import resource
import signal
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from fuse4d import Fuse4dError

__all__ = ["MEMORY_LIMIT_BYTES", "TIME_LIMIT_S", "ContractViolation", "check_contract"]

TIME_LIMIT_S = 10
MEMORY_LIMIT_BYTES = 2 * 1024**3


class ContractViolation(AssertionError):
    """A reader answered bad input with something other than a fuse4d error."""


class _Hang(BaseException):
    """Raised by the alarm; a BaseException so that no reader's ``except Exception`` eats it."""


def _address_space() -> int:
    with Path("/proc/self/statm").open() as f:
        return int(f.read().split()[0]) * resource.getpagesize()


@contextmanager
def _limits() -> Iterator[None]:
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    cap = _address_space() + MEMORY_LIMIT_BYTES
    if hard != resource.RLIM_INFINITY:
        cap = min(cap, hard)
    resource.setrlimit(resource.RLIMIT_AS, (cap, hard))

    def on_alarm(signum: int, frame: Any) -> None:
        raise _Hang

    previous = signal.signal(signal.SIGALRM, on_alarm)
    signal.alarm(TIME_LIMIT_S)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))


def check_contract(name: str, read: Callable[[Path], Any], path: Path) -> str:
    """Call ``read(path)`` under the limits; return ``"ok"`` or ``"error"`` (a fuse4d error).

    Warnings are allowed (a valid result may come with one), except a ``ResourceWarning``: a
    reader must close what it opened, also when it fails.

    Raises
    ------
    ContractViolation
        On any other exception, a hang, an out-of-memory or a file left open, naming the
        reader and the input.
    """
    fds = _open_fds()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        outcome = _call(name, read, path)
        if _open_fds() > fds:
            gc.collect()  # (slow) only when a file may have been left open
    leaked = [w for w in caught if issubclass(w.category, ResourceWarning)]
    if leaked or _open_fds() > fds:
        what = leaked[0].message if leaked else "a file descriptor was left open"
        raise ContractViolation(f"{name}: {what} (input {path})")
    return outcome


def _open_fds() -> int:
    return sum(1 for _ in Path("/proc/self/fd").iterdir())


def _call(name: str, read: Callable[[Path], Any], path: Path) -> str:
    try:
        with _limits():
            read(path)
    except Fuse4dError as exc:
        message = str(exc)
        if not message.strip() or "\n" in message.strip():
            raise ContractViolation(f"{name}: error message must be one line: {message!r}") from exc
        return "error"
    except _Hang:
        raise ContractViolation(f"{name}: hang (> {TIME_LIMIT_S} s) on {path}") from None
    except MemoryError:
        raise ContractViolation(f"{name}: memory blow-up (> 2 GB) on {path}") from None
    except Exception as exc:
        raise ContractViolation(f"{name}: {type(exc).__name__}: {exc} (input {path})") from exc
    return "ok"


# ----------------------------------------------------------------------------- validity
def check_frame(frame: Any, shape: tuple[int, int]) -> None:
    """A valid frame: float32 depth (mm, NaN or finite > 0), intensity in [0, 1], mask bool."""
    _check_depth(frame.depth, shape)
    _check_intensity(frame.intensity, shape)
    if frame.mask is not None:
        assert frame.mask.dtype == np.bool_, frame.mask.dtype
        assert frame.mask.shape == shape, (frame.mask.shape, shape)
    if frame.timestamp is not None:
        assert math.isfinite(frame.timestamp), frame.timestamp


def check_sequence(seq: Any) -> None:
    """A valid in-memory sequence (same rules as :func:`check_frame`, per frame)."""
    shape = seq.intrinsics.shape
    assert seq.depth.ndim == 3
    assert seq.depth.shape[0] >= 1
    for t in range(seq.depth.shape[0]):
        _check_depth(seq.depth[t], shape)
        _check_intensity(seq.intensity[t], shape)
    if seq.timestamps is not None:
        assert np.all(np.isfinite(seq.timestamps))


def _check_depth(depth: np.ndarray, shape: tuple[int, int]) -> None:
    assert depth.dtype == np.float32, depth.dtype
    assert depth.shape == shape, (depth.shape, shape)
    valid = ~np.isnan(depth)
    assert np.all(np.isfinite(depth[valid])), "depth holds inf"
    assert np.all(depth[valid] > 0), "depth holds values <= 0 that are not NaN"


def _check_intensity(intensity: np.ndarray, shape: tuple[int, int]) -> None:
    assert intensity.dtype == np.float32, intensity.dtype
    assert intensity.shape == shape, (intensity.shape, shape)
    assert np.all(np.isfinite(intensity)), "intensity holds NaN/inf"
    assert intensity.min() >= 0.0, "intensity < 0"
    assert intensity.max() <= 1.0, "intensity > 1"
