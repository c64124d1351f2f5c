"""Hypothesis strategies that damage files: bytes, text lines, JSON values, images, folders.

Every mutator is ``mutator(data, root)``: it draws from ``data`` (``st.data()``) and changes
the fixture under ``root`` in place.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from hypothesis import strategies as st

__all__ = [
    "INTERESTING_FLOATS",
    "INTERESTING_INTS",
    "Mutator",
    "delete_file",
    "duplicate_frame_number",
    "mutate_bytes",
    "mutate_json",
    "mutate_lines",
    "replace_image",
    "symlink_loop",
    "weird_text_values",
]

Mutator = Callable[[Any, Path], None]

INTERESTING_INTS = [0, -1, 1, 2, 255, 256, 65535, 65536, 2**31 - 1, -(2**31), 2**32, 2**63 - 1]
INTERESTING_FLOATS = [0.0, -0.0, -1.0, 1e-300, 1e300, 1e308, math.inf, -math.inf, math.nan,
                      0.5, 1.0, 1000.0, 3.4e38]  # fmt: skip
_BYTES = st.binary(min_size=1, max_size=16) | st.sampled_from(
    [b"\x00", b"\xff", b"\x7f", b"\x80", b"\xff\xff\xff\xff", b"\x00\x00\x00\x00", b"9", b"-"]
)


def files_under(root: Path) -> list[Path]:
    """Regular files under ``root`` (sorted, so that draws are reproducible)."""
    return sorted(p for p in root.rglob("*") if p.is_file() and not p.is_symlink())


def _pick(data: Any, items: list[Any], label: str) -> Any:
    return items[data.draw(st.integers(0, len(items) - 1), label=label)]


def mutate_bytes(data: Any, root: Path, *, files: list[Path] | None = None) -> None:
    """1-4 byte-level edits (flip, truncate, delete, insert, overwrite, duplicate) of one file."""
    candidates = files if files is not None else [root] if root.is_file() else files_under(root)
    path = _pick(data, candidates, "file")
    blob = bytearray(path.read_bytes())
    # most format checks sit in the first bytes: bias edits towards the header
    header_bias = data.draw(st.booleans(), label="header bias")
    for _ in range(data.draw(st.integers(1, 4), label="edits")):
        n = len(blob)
        limit = min(n, 64) if header_bias else n
        pos = data.draw(st.integers(0, max(limit - 1, 0)), label="pos")
        op = data.draw(
            st.sampled_from(["flip", "truncate", "delete", "insert", "overwrite", "duplicate"])
        )
        if op == "flip" and n:
            blob[pos] ^= data.draw(st.integers(1, 255))
        elif op == "truncate":
            del blob[pos:]
        elif op == "delete":
            del blob[pos : pos + data.draw(st.integers(1, 64))]
        elif op == "insert":
            blob[pos:pos] = data.draw(_BYTES)
        elif op == "overwrite":
            chunk = data.draw(_BYTES)
            blob[pos : pos + len(chunk)] = chunk
        elif op == "duplicate":
            blob[pos:pos] = blob[pos : pos + data.draw(st.integers(1, 256))]
    path.write_bytes(bytes(blob))


def weird_text_values() -> st.SearchStrategy[str]:
    """Tokens that break number and path parsing."""
    return st.sampled_from(
        ["nan", "inf", "-inf", "-1", "0", "1e400", "1e-400", "0x10", "", " ", "abc", "1,5",
         "99999999999999999999", "../outside.png", "/etc/passwd", "/dev/zero", "\x00", "é"]
    ) | st.text(max_size=8)  # fmt: skip


def mutate_lines(data: Any, path: Path) -> None:
    """Edit a text file line by line: replace a token, drop, duplicate or swap lines."""
    lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    if not lines:
        lines = [""]
    for _ in range(data.draw(st.integers(1, 3), label="line edits")):
        k = data.draw(st.integers(0, len(lines) - 1), label="line")
        op = data.draw(st.sampled_from(["token", "drop", "duplicate", "swap", "append"]))
        if op == "token":
            parts = lines[k].split(" ")
            j = data.draw(st.integers(0, len(parts) - 1))
            parts[j] = data.draw(weird_text_values())
            lines[k] = " ".join(parts)
        elif op == "drop" and len(lines) > 1:
            del lines[k]
        elif op == "duplicate":
            lines.insert(k, lines[k])
        elif op == "swap":
            j = data.draw(st.integers(0, len(lines) - 1))
            lines[k], lines[j] = lines[j], lines[k]
        elif op == "append":
            lines.append(data.draw(weird_text_values()))
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def _json_values() -> st.SearchStrategy[Any]:
    scalars = (
        st.none()
        | st.booleans()
        | st.sampled_from(INTERESTING_INTS)
        | st.sampled_from(INTERESTING_FLOATS)
        | st.integers()
        | st.floats()
        | weird_text_values()
    )
    return st.recursive(
        scalars,
        lambda children: (
            st.lists(children, max_size=4)
            | st.dictionaries(st.text(max_size=4), children, max_size=3)
        ),
        max_leaves=6,
    )


def _leaves(value: Any, prefix: tuple = ()) -> list[tuple]:
    out = [prefix]
    if isinstance(value, dict):
        for k, v in value.items():
            out += _leaves(v, (*prefix, k))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            out += _leaves(v, (*prefix, i))
    return out


def mutate_json(data: Any, path: Path) -> None:
    """Replace, delete or duplicate values at random places of a JSON document."""
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (ValueError, UnicodeDecodeError):
        doc = {}
    for _ in range(data.draw(st.integers(1, 3), label="json edits")):
        where = _pick(data, _leaves(doc), "json path")
        op = data.draw(st.sampled_from(["replace", "delete", "duplicate"]))
        if not where:
            if op == "replace":
                doc = data.draw(_json_values())
            continue
        parent = doc
        for key in where[:-1]:
            parent = parent[key]
        key = where[-1]
        if op == "replace":
            parent[key] = data.draw(_json_values())
        elif op == "delete":
            del parent[key]
        elif op == "duplicate" and isinstance(parent, list):
            parent.insert(key, json.loads(json.dumps(parent[key])))
    path.write_text(json.dumps(doc), encoding="utf-8")  # NaN/Infinity literals allowed


def random_image(data: Any) -> np.ndarray:
    """A small image of a random dtype, size and channel count."""
    h = data.draw(st.integers(1, 20), label="h")
    w = data.draw(st.integers(1, 20), label="w")
    channels = data.draw(st.sampled_from([1, 2, 3, 4]), label="channels")
    dtype = data.draw(st.sampled_from(["uint8", "uint16"]), label="dtype")
    top = 255 if dtype == "uint8" else 65535
    fill = data.draw(st.sampled_from([0, 1, top, -1]), label="fill")
    shape = (h, w) if channels == 1 else (h, w, channels)
    if fill < 0:
        seed = data.draw(st.integers(0, 2**16))
        return np.random.default_rng(seed).integers(0, top + 1, shape).astype(dtype)
    return np.full(shape, fill, dtype)


def replace_image(data: Any, path: Path) -> None:
    """Overwrite an image file with another (random size, dtype, channels; PNG/JPEG/TIFF)."""
    image = random_image(data)
    ext = data.draw(st.sampled_from([".png", ".jpg", ".tiff"]), label="codec")
    if ext == ".jpg" and (image.dtype != np.uint8 or (image.ndim == 3 and image.shape[2] == 2)):
        ext = ".png"
    if ext == ".png" and image.ndim == 3 and image.shape[2] == 2:
        image = image[..., 0]
    ok, buf = cv2.imencode(ext, image)
    if ok:
        path.write_bytes(buf.tobytes())


def delete_file(data: Any, root: Path) -> None:
    """Remove one file."""
    files = files_under(root)
    if files:
        _pick(data, files, "delete").unlink()


def duplicate_frame_number(data: Any, root: Path) -> None:
    """Copy a numbered frame under the same number with other zero padding (``1.png``)."""
    files = [p for p in files_under(root) if p.stem.isdigit() and len(p.stem) > 1]
    if files:
        p = _pick(data, files, "duplicate")
        p.with_name(f"{int(p.stem)}{p.suffix}").write_bytes(p.read_bytes())


def symlink_loop(data: Any, root: Path) -> None:
    """Replace a file by a symlink to itself, or a folder by a symlink to its parent."""
    entries = sorted(p for p in root.rglob("*") if not p.is_symlink())
    if not entries:
        return
    p = _pick(data, entries, "symlink")
    if p.is_dir():
        target = p.parent
        _rmtree(p)
        p.symlink_to(target)
    else:
        p.unlink()
        p.symlink_to(p.name)  # ELOOP on open


def _rmtree(path: Path) -> None:
    import shutil

    shutil.rmtree(path)
