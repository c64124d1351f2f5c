"""Optional dependencies of the sensor readers/writers, imported on demand with a clear message.

``rosbags`` (ROS 1/ROS 2/MCAP bags, RealSense ``.bag``/``.db3``), ``av`` (PyAV: Azure Kinect /
Orbbec ``.mkv`` and FFV1 depth video) and ``zarr`` (zarr v3 stores) come with the ``sensors``
extra: ``pip install "fuse4d[sensors]"``.
"""

from __future__ import annotations

import importlib
from types import ModuleType

from ..errors import Fuse4dError

__all__ = ["MissingDependencyError", "require"]


class MissingDependencyError(Fuse4dError, ImportError):
    """An optional package needed for a file format is not installed.

    Subclasses :class:`ImportError` (what it is) and :class:`ValueError` (so that the CLI
    reports it as one line with exit code 2, like every other input problem).
    """


def require(module: str, *, what: str, extra: str = "sensors") -> ModuleType:
    """Import ``module`` or raise :class:`MissingDependencyError` naming the extra to install.

    Parameters
    ----------
    module : str
        Importable name (``"rosbags.highlevel"``, ``"av"``, ``"zarr"``).
    what : str
        What needs it, for the message (``"reading ROS bags"``).
    extra : str, optional
        The fuse4d extra that provides it.
    """
    try:
        return importlib.import_module(module)
    except ImportError:
        top = module.split(".")[0]
        raise MissingDependencyError(
            f"{what} needs the optional package '{top}', which is not installed; "
            f'install it with: pip install "fuse4d[{extra}]"'
        ) from None
