"""Whether the user interrupted this command (Ctrl-C, SIGTERM, SIGHUP).

One flag for the CLI and the code that handles signals itself (``fuse4d live``): an
interrupt raised inside numba's compiler (a ctypes callback) surfaces as another error, and
the CLI tells it from a bug by this flag.
"""

from __future__ import annotations

import threading

__all__ = ["INTERRUPTED"]

#: Set by a signal handler; cleared by :func:`fuse4d.cli.main` at the start of each command.
INTERRUPTED = threading.Event()
