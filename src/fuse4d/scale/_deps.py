"""The ``scale`` extra: dask[array], distributed (optional at run time) and zarr >= 3."""

from __future__ import annotations

import importlib.util

__all__ = ["require_scale_extra"]

_HINT = "install the extra: pip install 'fuse4d[scale]' (dask[array], distributed, zarr>=3)"


def require_scale_extra(*, distributed: bool = False) -> None:
    """Raise one clear ImportError when the dask engine's dependencies are missing.

    Parameters
    ----------
    distributed : bool
        Also require ``dask.distributed`` (needed for ``processes`` via LocalCluster and
        ``tcp://`` schedulers).

    Raises
    ------
    ImportError
        Naming the missing packages and the extra to install.
    """
    needed = ["dask", "zarr"] + (["distributed"] if distributed else [])
    missing = [name for name in needed if importlib.util.find_spec(name) is None]
    if not missing and importlib.util.find_spec("dask.array") is not None:
        try:
            import dask.array  # noqa: F401  (needs numpy + toolz, i.e. dask[array])
        except ImportError as exc:
            missing.append(f"dask[array] ({exc})")
    if not missing:
        import zarr

        if int(zarr.__version__.split(".")[0]) < 3:
            missing.append(f"zarr>=3 (found {zarr.__version__})")
    if missing:
        raise ImportError(f"fuse4d's dask engine needs {', '.join(missing)}; {_HINT}")
