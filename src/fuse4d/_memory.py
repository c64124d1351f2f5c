"""Buffers whose memory is written when they are made (issue 13), and the memory a process
can still take (:func:`available_memory`). Private.

``np.zeros`` and ``np.empty`` only reserve address space: the kernel maps each page at its
first write. A streaming engine that makes its ring buffers that way pays for the mapping
during its first frames, inside the per-frame timings, instead of at construction. On this
project's 2-core machine a 4 KiB page fault costs about 1.6 us, and at times 30 us or more
(while the host reclaims the guest's memory): writing the flow ring buffers of a 600 x 600,
9-frame engine then added 15-30 ms to each of the first frames, so that whole
``fuse4d bench`` runs measured a flow stage of 22-38 ms instead of 8-11.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["available_memory", "committed"]


def committed(shape: int | tuple[int, ...], dtype: Any, value: Any = 0) -> np.ndarray:
    """A new array of ``shape`` and ``dtype`` filled with ``value``, every page written now."""
    return np.full(shape, value, dtype)


def available_memory() -> int | None:
    """Bytes this process can still allocate, as far as the system says (Linux): the smallest
    of MemAvailable + SwapFree, the address-space limit (``ulimit -v``) less what the process
    maps, and the cgroup's ``memory.max`` less ``memory.current`` plus its reclaimable
    (inactive) file cache. None where none is known.

    The one home of this check: the synthetic scenes' size check and
    :class:`fuse4d.FusionEngine`'s buffers use it."""
    import os
    from pathlib import Path

    def read(path: str) -> str | None:
        try:
            return Path(path).read_text()
        except OSError:
            return None

    def field_kib(text: str | None, name: str) -> int | None:
        for line in (text or "").splitlines():
            if line.startswith(name + ":"):
                return int(line.split()[1]) * 1024
        return None

    known: list[int] = []
    meminfo = read("/proc/meminfo")
    available = field_kib(meminfo, "MemAvailable")
    if available is not None:
        known.append(available + (field_kib(meminfo, "SwapFree") or 0))
    try:
        import resource

        soft = resource.getrlimit(resource.RLIMIT_AS)[0]
        mapped = field_kib(read(f"/proc/{os.getpid()}/status"), "VmSize")
        if soft != resource.RLIM_INFINITY and mapped is not None:
            known.append(soft - mapped)
    except (ImportError, OSError, ValueError):
        pass
    limit, used = read("/sys/fs/cgroup/memory.max"), read("/sys/fs/cgroup/memory.current")
    if limit is not None and used is not None and limit.strip().isdigit():
        # memory.current counts the file cache, which the kernel gives back on demand (a
        # container that had read a few GB looked full): add back its clean part, active
        # and inactive (the kernel keeps inactive_file at a fraction of the cache)
        stat: dict[str, int] = {}
        for line in (read("/sys/fs/cgroup/memory.stat") or "").splitlines():
            name, _, value = line.partition(" ")
            if value.strip().isdigit():
                stat[name] = int(value)
        cache = max(
            stat.get("file", 0) - stat.get("file_dirty", 0) - stat.get("file_writeback", 0), 0
        )
        known.append(int(limit) - int(used) + cache)
    return max(min(known), 0) if known else None
