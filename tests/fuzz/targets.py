"""One :class:`FuzzTarget` per reader: how to build a valid fixture, damage it, read it.

To fuzz a new reader (e.g. a bag/db3/mkv sensor reader), append an entry to :data:`TARGETS`:
a ``build(folder) -> path`` that writes a small valid input (from real data when it is
available), the ``mutators`` that apply to it, and a ``read(path)`` that reads everything and
checks the result with :mod:`.contract`'s validity checks.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from hypothesis import strategies as st

from fuse4d import Intrinsics, Sequence
from fuse4d.config import load_config
from fuse4d.flow import read_flo, write_flo
from fuse4d.io import (
    open_frames,
    read_camera_json,
    read_mask,
    read_npz_extra,
    read_ply,
    write_frame_folder,
    write_npz,
    write_ply,
)
from fuse4d.sequence import GroundTruth

from . import mutate as m
from .contract import check_frame, check_sequence

__all__ = ["TARGETS", "FuzzTarget", "shared_data_dir"]

H, W, T = 12, 16, 3


def shared_data_dir() -> Path:
    """Same rule as ``tests/conftest.py``."""
    import os

    env = os.environ.get("FUSE4D_DATA")
    root = Path(__file__).resolve().parents[2]
    return Path(env) if env else root.parent / "shared" / "data"


@dataclass(frozen=True)
class FuzzTarget:
    """A reader under fuzz.

    Attributes
    ----------
    name : str
        Test id.
    build : callable
        ``build(folder) -> path``: write a small valid input under ``folder``, return what
        ``read`` takes. Called once per session; each example works on a fresh copy.
    read : callable
        ``read(path)``: read everything (metadata and every frame) and check the result.
    mutators : list of callables
        ``mutator(data, root)``, see :mod:`.mutate`; one is drawn per example (repeatable).
    """

    name: str
    build: Callable[[Path], Path]
    read: Callable[[Path], Any]
    mutators: list[m.Mutator] = field(default_factory=list)


# ----------------------------------------------------------------------------- fixtures
def _sequence(rng: np.random.Generator | None = None) -> Sequence:
    rng = rng or np.random.default_rng(0)
    yy, xx = np.mgrid[0:H, 0:W]
    depth = (800.0 + 3.0 * xx + rng.normal(0, 0.5, (T, H, W))).astype(np.float32)
    depth[:, 0, 0] = np.nan
    tex = np.clip(0.5 + 0.4 * np.sin(xx / 2.0) * np.cos(yy / 3.0), 0, 1).astype(np.float32)
    intensity = np.broadcast_to(tex, (T, H, W)).copy()
    mask = np.zeros((T, H, W), bool)
    mask[:, 3:8, 4:10] = True
    k = Intrinsics(20.0, 21.0, 7.5, 5.5, width=W, height=H)
    gt = GroundTruth(
        depth=depth + 0.1,
        mask=mask,
        flow=np.zeros((T - 1, H, W, 2), np.float32),
        extra={"radius": 3.0},
    )
    return Sequence(depth, intensity, k, timestamps=np.arange(T) / 30.0, fps=30.0,
                    ground_truth=gt, name="fuzz")  # fmt: skip


def _build_npz(folder: Path) -> Path:
    return write_npz(_sequence(), folder / "seq.npz", extra={"support": np.ones((T, H, W))})


def _build_folder(folder: Path) -> Path:
    out = folder / "seq"
    seq = _sequence()
    seq = Sequence(seq.depth, seq.intensity, seq.intrinsics, timestamps=seq.timestamps,
                   fps=30.0, ground_truth=GroundTruth(mask=seq.ground_truth.mask))  # fmt: skip
    write_frame_folder(seq, out, depth_unit_mm=0.1)
    return out


def _build_camera_json(folder: Path) -> Path:
    path = folder / "camera.json"
    cam = {"fx": 525.0, "fy": 525.0, "cx": 319.5, "cy": 239.5, "depth_unit_mm": 1.0,
           "fps": 30.0, "width": 640, "height": 480}  # fmt: skip
    path.write_text(json.dumps(cam, indent=2))
    return path


def _write_png(path: Path, image: np.ndarray) -> None:
    ok, buf = cv2.imencode(path.suffix, image)
    assert ok
    path.write_bytes(buf.tobytes())


def _build_tum(folder: Path) -> Path:
    root = folder / "tum"
    (root / "rgb").mkdir(parents=True)
    (root / "depth").mkdir()
    seq = _sequence()
    rgb_lines, depth_lines = ["# color images", "# timestamp filename"], ["# depth maps"]
    for t in range(T):
        stamp = 1305031102.175304 + t / 30.0
        d = np.nan_to_num(seq.depth[t] * 5.0).astype(np.uint16)  # 5000 units per metre
        _write_png(root / "depth" / f"{stamp:.6f}.png", d)
        gray = (seq.intensity[t] * 255).astype(np.uint8)
        _write_png(root / "rgb" / f"{stamp + 0.004:.6f}.png", cv2.merge([gray, gray, gray]))
        rgb_lines.append(f"{stamp + 0.004:.6f} rgb/{stamp + 0.004:.6f}.png")
        depth_lines.append(f"{stamp:.6f} depth/{stamp:.6f}.png")
    (root / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
    (root / "depth.txt").write_text("\n".join(depth_lines) + "\n")
    cam = {"fx": 20.0, "fy": 21.0, "cx": 7.5, "cy": 5.5}
    (root / "camera.json").write_text(json.dumps(cam))
    return root


def _build_cv2xml(folder: Path) -> Path:
    """Two real frames of the UvA person recording (synthetic ones when absent)."""
    root = folder / "cv2xml"
    root.mkdir()
    real = shared_data_dir() / "uva_cv2_person_turning"
    if (real / "0000000000_depth.png").is_file():
        for k in range(2):
            for suffix in (".jpg", "_camera.xml", "_depth.png", "_mask.jpg"):
                shutil.copyfile(real / f"{k:010d}{suffix}", root / f"{k:010d}{suffix}")
        return root
    seq = _sequence()  # pragma: no cover - only without the shared data
    xml = (
        '<?xml version="1.0"?>\n<opencv_storage>\n<intrinsic type_id="opencv-matrix">\n'
        "  <rows>3</rows>\n  <cols>3</cols>\n  <dt>f</dt>\n"
        "  <data>\n    20. 0. 7.5 0. 21. 5.5 0. 0. 1.</data></intrinsic>\n</opencv_storage>\n"
    )
    for k in range(2):
        _write_png(root / f"{k:010d}_depth.png", np.nan_to_num(seq.depth[k]).astype(np.uint16))
        _write_png(root / f"{k:010d}.jpg", (seq.intensity[k] * 255).astype(np.uint8))
        _write_png(root / f"{k:010d}_mask.jpg", seq.ground_truth.mask[k].astype(np.uint8) * 255)
        (root / f"{k:010d}_camera.xml").write_text(xml)
    return root


def _build_framesjson(folder: Path) -> Path:
    """The first two real frames of the static-room recording (synthetic when absent)."""
    root = folder / "framesjson"
    root.mkdir()
    real = shared_data_dir() / "static_room_rgbd"
    if (real / "frames.json").is_file():
        doc = json.loads((real / "frames.json").read_text())
        entries = doc["root"][:2]
        for e in entries:
            for key in ("depth_image", "rgb_image"):
                shutil.copyfile(real / e[key], root / e[key])
        (root / "frames.json").write_text(json.dumps({"root": entries}, indent=1))
        return root
    seq = _sequence()  # pragma: no cover - only without the shared data
    entries = []
    for k in range(2):
        _write_png(root / f"d{k}.png", np.nan_to_num(seq.depth[k]).astype(np.uint16))
        _write_png(root / f"c{k}.png", (seq.intensity[k] * 255).astype(np.uint8))
        entries.append({"info": {"kcam": {"matrix": [[20, 0, 7.5], [0, 21, 5.5], [0, 0, 1]],
                                          "image_size": [W, H]},
                                 "depth_scale": 0.001, "depth_bias": 0.0, "timestamp": k * 33},
                        "depth_image": f"d{k}.png", "rgb_image": f"c{k}.png"})  # fmt: skip
    (root / "frames.json").write_text(json.dumps({"root": entries}))
    return root


def _build_flo(folder: Path) -> Path:
    real = shared_data_dir() / "middlebury_flow" / "other-gt-flow" / "RubberWhale" / "flow10.flo"
    if real.is_file():
        flow = read_flo(real)[::8, ::8]  # real values (with unknowns), small
    else:  # pragma: no cover
        flow = np.random.default_rng(1).normal(0, 2, (6, 5, 2)).astype(np.float32)
        flow[0, 0] = np.nan
    return write_flo(flow, folder / "flow.flo")


def _build_ply(folder: Path) -> Path:
    seq = _sequence()
    from fuse4d import depth_to_points

    points = depth_to_points(seq.depth[0], seq.intrinsics)
    path = folder / "cloud.ply"
    write_ply(points, path, colors=seq.intensity[0])
    return path


def _build_toml(folder: Path) -> Path:
    path = folder / "config.toml"
    path.write_text(
        'preset = "fast"\n\n[fusion]\nnum_frames = 5\nspatial_radius = 2\n'
        'sigma_temporal = "inf"\ncausal = false\n\n[flow]\nmethod = "dis"\n\n'
        '[flow.params]\npreset = "medium"\n'
    )
    return path


def _build_mask_npz(folder: Path) -> Path:
    path = folder / "roi.npz"
    np.savez(path, roi=_sequence().ground_truth.mask)
    return path


# ----------------------------------------------------------------------------- readers
def _read_recording(path: Path) -> None:
    with open_frames(path) as reader:
        shape = reader.intrinsics.shape
        assert len(reader) >= 1
        for frame in reader:
            check_frame(frame, shape)
        check_sequence(reader.read_sequence())


def _read_npz(path: Path) -> None:
    _read_recording(path)
    read_npz_extra(path)


def _read_camera_json(path: Path) -> None:
    cam = read_camera_json(path)
    for key in ("fx", "fy", "cx", "cy", "depth_unit_mm"):
        assert isinstance(cam[key], float)
    assert cam["fx"] > 0
    assert cam["fy"] > 0


def _read_flo(path: Path) -> None:
    flow = read_flo(path)
    assert flow.dtype == np.float32
    assert flow.ndim == 3
    assert flow.shape[2] == 2
    valid = ~np.isnan(flow)
    assert np.all(np.isfinite(flow[valid]))


def _read_ply(path: Path) -> None:
    points, colors = read_ply(path)
    assert points.dtype == np.float32
    assert points.ndim == 2
    assert points.shape[1] == 3
    if colors is not None:
        assert colors.shape == points.shape


def _read_toml(path: Path) -> None:
    chosen = load_config(path)
    chosen.flow.build_params()


def _read_mask(path: Path) -> None:
    mask = read_mask(path)
    assert mask.dtype == np.bool_
    assert mask.ndim in (2, 3)


# ----------------------------------------------------------------------------- mutators
def _on(pattern: str, mutator: Callable[[Any, Path], None]) -> m.Mutator:
    """Apply a per-file mutator to one file under the root matching ``pattern``."""

    def apply(data: Any, root: Path) -> None:
        base = root if root.is_dir() else root.parent
        files = sorted(p for p in base.rglob(pattern) if p.is_file() and not p.is_symlink())
        if files:
            mutator(data, files[data.draw(st.integers(0, len(files) - 1), label=pattern)])

    apply.__name__ = f"{mutator.__name__}({pattern})"
    return apply


def _bytes_of(pattern: str) -> m.Mutator:
    def apply(data: Any, root: Path) -> None:
        base = root if root.is_dir() else root.parent
        files = sorted(p for p in base.rglob(pattern) if p.is_file() and not p.is_symlink())
        if files:
            m.mutate_bytes(data, base, files=files)

    apply.__name__ = f"mutate_bytes({pattern})"
    return apply


_ARRAY_DTYPES = ["float32", "float64", "float16", "int16", "uint16", "uint8", "int64", "bool",
                 "complex64", "<U3", "S2", "datetime64[s]", "f4,i2"]  # fmt: skip


def _array(data: Any, like: tuple[int, ...]) -> np.ndarray:
    choice = data.draw(st.sampled_from(["valid", "shape", "empty", "scalar"]), label="shape kind")
    if choice == "valid":
        shape = like
    elif choice == "empty":
        shape = tuple(0 if i == 0 else s for i, s in enumerate(like)) or (0,)
    elif choice == "scalar":
        shape = ()
    else:
        shape = tuple(data.draw(st.lists(st.integers(0, 5), max_size=4), label="shape"))
    dtype = np.dtype(data.draw(st.sampled_from(_ARRAY_DTYPES), label="dtype"))
    arr = np.zeros(shape, dtype)
    if dtype.kind in "fc" and arr.size:
        value = data.draw(st.sampled_from(m.INTERESTING_FLOATS), label="fill")
        with np.errstate(over="ignore", invalid="ignore"):
            arr[...] = value
            arr.flat[0] = 500.0
    elif dtype.kind in "iu" and arr.size:
        value = data.draw(st.sampled_from(m.INTERESTING_INTS), label="fill")
        with np.errstate(over="ignore"):
            arr[...] = np.array(value).astype(dtype)
    return arr


def npz_arrays(data: Any, root: Path) -> None:
    """Rewrite the npz with some members replaced by arrays of wrong dtype/shape/values."""
    path = root
    keys = ["depth", "intensity", "intrinsics", "timestamps", "fps", "name", "depth_gt",
            "mask_gt", "flow_gt", "gt_radius", "support"]  # fmt: skip
    like = {"depth": (T, H, W), "intensity": (T, H, W), "intrinsics": (4,), "timestamps": (T,),
            "fps": (), "name": (), "depth_gt": (T, H, W), "mask_gt": (T, H, W),
            "flow_gt": (T - 1, H, W, 2), "gt_radius": (), "support": (T, H, W)}  # fmt: skip
    with path.open("rb") as f, np.load(f, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    for _ in range(data.draw(st.integers(1, 3), label="array edits")):
        key = data.draw(st.sampled_from(keys), label="key")
        if data.draw(st.booleans(), label="drop"):
            arrays.pop(key, None)
        else:
            arrays[key] = _array(data, like[key])
    save = np.savez_compressed if data.draw(st.booleans(), label="compress") else np.savez
    with path.open("wb") as f:
        save(f, allow_pickle=False, **arrays)


def npz_depth_values(data: Any, root: Path) -> None:
    """Valid shapes and dtypes, hostile values: NaN/inf/negative/huge depth and intensity."""
    with root.open("rb") as f, np.load(f, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    for key in ("depth", "intensity", "intrinsics", "timestamps"):
        if data.draw(st.booleans(), label=f"touch {key}"):
            arr = arrays[key].astype(np.float64)
            idx = data.draw(st.integers(0, arr.size - 1), label="index")
            arr.flat[idx] = data.draw(st.sampled_from(m.INTERESTING_FLOATS), label="value")
            if data.draw(st.booleans(), label="all"):
                arr[...] = arr.flat[idx]
            with np.errstate(over="ignore", invalid="ignore"):
                arrays[key] = arr.astype(arrays[key].dtype)
    with root.open("wb") as f:
        np.savez(f, allow_pickle=False, **arrays)


def camera_json_values(data: Any, root: Path) -> None:
    """camera.json with zero, absurd, non-numeric or missing intrinsics."""
    path = root if root.suffix == ".json" else root / "camera.json"
    if not path.is_file():
        return
    try:
        cam = json.loads(path.read_text())
    except ValueError:
        cam = {}
    if not isinstance(cam, dict):
        cam = {}
    key = data.draw(st.sampled_from(["fx", "fy", "cx", "cy", "depth_unit_mm", "fps", "width",
                                     "height", "extra"]), label="cam key")  # fmt: skip
    value = data.draw(
        st.sampled_from(m.INTERESTING_FLOATS + m.INTERESTING_INTS + [None, "1", True, [1], {}]),
        label="cam value",
    )
    cam[key] = value
    path.write_text(json.dumps(cam))


def mismatched_sizes(data: Any, root: Path) -> None:
    """One image of the recording replaced by a valid image of another size or type."""
    images = sorted(p for p in root.rglob("*") if p.suffix in (".png", ".jpg") and p.is_file())
    if images:
        m.replace_image(data, images[data.draw(st.integers(0, len(images) - 1), label="image")])


def flo_header(data: Any, root: Path) -> None:
    """A .flo whose width/height are zero, negative, huge or do not match the data."""
    blob = bytearray(root.read_bytes())
    width = data.draw(st.sampled_from([*m.INTERESTING_INTS, 99999]), label="width")
    height = data.draw(st.sampled_from([*m.INTERESTING_INTS, 99999]), label="height")
    blob[4:12] = np.array([width, height], dtype=np.int64).astype("<i4").tobytes()
    root.write_bytes(bytes(blob))


def ply_header(data: Any, root: Path) -> None:
    """Edit one header line of a PLY (counts, types, duplicated or missing properties)."""
    blob = root.read_bytes()
    end = blob.index(b"end_header\n") + len(b"end_header\n")
    lines = blob[:end].decode("ascii").splitlines()
    k = data.draw(st.integers(0, len(lines) - 1), label="header line")
    new = data.draw(
        st.sampled_from([
            "element vertex -1", "element vertex abc", "element vertex", "element vertex 1e9",
            "element vertex 99999999999999999999", "element face 3", "property float x",
            "property list uchar int vertex_indices", "property quad x", "property float",
            "format ascii 1.0", "format binary_big_endian 1.0", "comment", "", "ply",
        ]) | m.weird_text_values(),
        label="header value",
    )  # fmt: skip
    op = data.draw(st.sampled_from(["replace", "insert", "delete"]), label="header op")
    if op == "replace":
        lines[k] = new
    elif op == "insert":
        lines.insert(k, new)
    elif len(lines) > 1:
        del lines[k]
    root.write_bytes(("\n".join(lines) + "\n").encode("utf-8") + blob[end:])


def _toml_value(data: Any) -> str:
    return data.draw(
        st.sampled_from([
            "0", "-1", "1", "3", "2.5", "-0.0", "inf", "-inf", "nan", "1e308", '"inf"', '"abc"',
            "true", "false", "[]", "[1, 2]", "{}", '{a = 1}', "99999999999999999999",
            "9223372036854775807", '"fast"', '"paper"', '"dis"', '"nope"', '"medium"',
            "1979-05-27", '""',
        ]),
        label="toml value",
    )  # fmt: skip


def toml_values(data: Any, root: Path) -> None:
    """A configuration file with known keys holding values of the wrong type or range."""
    from dataclasses import fields

    from fuse4d.config import FusionParams

    fusion_keys = [f.name for f in fields(FusionParams)] + ["unknown"]
    lines = []
    if data.draw(st.booleans(), label="preset"):
        lines.append(f"preset = {_toml_value(data)}")
    if data.draw(st.booleans(), label="top-level junk"):
        lines.append(f"junk = {_toml_value(data)}")
    lines.append("[fusion]")
    keys = data.draw(st.lists(st.sampled_from(fusion_keys), max_size=4, unique=True))
    lines += [f"{key} = {_toml_value(data)}" for key in keys]
    kind = data.draw(st.sampled_from(["table", "scalar", "none"]), label="flow kind")
    if kind == "scalar":
        lines.insert(0, f"flow = {_toml_value(data)}")
    elif kind == "table":
        lines.append("[flow]")
        if data.draw(st.booleans()):
            lines.append(f"method = {_toml_value(data)}")
        ptype = data.draw(st.sampled_from(["table", "scalar", "none"]), label="params kind")
        if ptype == "scalar":
            lines.append(f"params = {_toml_value(data)}")
        elif ptype == "table":
            lines.append("[flow.params]")
            pkeys = ["preset", "patch_size", "patch_stride", "levels", "iterations",
                     "num_particles", "unknown", "finest_scale", "winsize"]  # fmt: skip
            keys = data.draw(st.lists(st.sampled_from(pkeys), max_size=3, unique=True))
            lines += [f"{key} = {_toml_value(data)}" for key in keys]
    root.write_text("\n".join(lines) + "\n")


def tum_lists(data: Any, root: Path) -> None:
    m.mutate_lines(data, root / data.draw(st.sampled_from(["rgb.txt", "depth.txt"])))


# ----------------------------------------------------------------------------- registry
_FOLDER_COMMON: list[m.Mutator] = [
    m.mutate_bytes,
    m.delete_file,
    m.duplicate_frame_number,
    m.symlink_loop,
    mismatched_sizes,
]

TARGETS: list[FuzzTarget] = [
    FuzzTarget("npz", _build_npz, _read_npz,
               [m.mutate_bytes, npz_arrays, npz_depth_values]),
    FuzzTarget("folder", _build_folder, _read_recording,
               [*_FOLDER_COMMON, camera_json_values, _on("timestamps.txt", m.mutate_lines)]),
    FuzzTarget("camera-json", _build_camera_json, _read_camera_json,
               [m.mutate_bytes, camera_json_values, _on("camera.json", m.mutate_json)]),
    FuzzTarget("tum", _build_tum, _read_recording,
               [*_FOLDER_COMMON, tum_lists, camera_json_values]),
    FuzzTarget("cv2-xml", _build_cv2xml, _read_recording,
               [*_FOLDER_COMMON, _bytes_of("*.xml"), _on("*.xml", m.mutate_lines)]),
    FuzzTarget("frames-json", _build_framesjson, _read_recording,
               [*_FOLDER_COMMON, _bytes_of("frames.json"), _on("frames.json", m.mutate_json)]),
    FuzzTarget("flo", _build_flo, _read_flo, [m.mutate_bytes, flo_header]),
    FuzzTarget("ply", _build_ply, _read_ply, [m.mutate_bytes, ply_header]),
    FuzzTarget("toml", _build_toml, _read_toml,
               [m.mutate_bytes, toml_values, _on("config.toml", m.mutate_lines)]),
    FuzzTarget("mask-npz", _build_mask_npz, _read_mask, [m.mutate_bytes, npz_arrays]),
]  # fmt: skip
