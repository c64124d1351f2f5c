"""CLI commands: ``info``, ``export-ply`` (placeholder module, filled by the I/O work)."""

from __future__ import annotations
