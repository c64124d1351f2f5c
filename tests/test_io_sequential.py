"""SequentialReader: in-order reads resume one decoding pass; other reads restart it."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from fuse4d.camera import Intrinsics
from fuse4d.errors import InputFileError
from fuse4d.io._base import Frame, SequentialReader


class _Counting(SequentialReader):
    """Frames 0..n-1 whose depth is the frame index; frames >= ``lost`` never decode."""

    format = "test"
    _missing_frame = "frame lost"

    def __init__(self, n: int, lost: int | None = None) -> None:
        self.path = Path("counting.test")
        self.intrinsics = Intrinsics(100.0, 100.0, 1.5, 1.5, width=4, height=4)
        self._n, self._lost = n, lost
        self.passes: list[int] = []

    def __len__(self) -> int:
        return self._n

    def _stream(self, k0: int, stop: int | None = None) -> Iterator[Frame]:
        self.passes.append(k0)
        for k in range(k0, self._n if stop is None else stop):
            if self._lost is not None and k >= self._lost:
                return
            d = np.full((4, 4), float(k), np.float32)
            yield Frame(index=k, depth=d, intensity=d / 10.0)

    def close(self) -> None:
        self._close_stream()


def test_in_order_reads_share_one_pass_and_seeks_restart_it():
    r = _Counting(6)
    assert [int(r.read_frame(k).depth[0, 0]) for k in (0, 1, 2)] == [0, 1, 2]
    assert r.passes == [0]
    assert int(r.read_frame(4).depth[0, 0]) == 4
    assert int(r.read_frame(5).depth[0, 0]) == 5
    assert int(r.read_frame(-6).depth[0, 0]) == 0
    assert r.passes == [0, 4, 0]
    assert [int(f.depth[0, 0]) for f in r.iter_frames("2:4")] == [2, 3]
    r.close()


def test_a_frame_the_pass_does_not_reach_names_file_and_frame():
    r = _Counting(5, lost=3)
    r.read_frame(2)
    with pytest.raises(InputFileError, match=r"counting\.test.*frame lost") as e:
        r.read_frame(3)
    assert "3" in str(e.value)
    assert int(r.read_frame(1).depth[0, 0]) == 1  # a later read starts a fresh pass


@pytest.mark.parametrize("kind", ["folder", "mkv", "zarr"])
def test_every_writer_refuses_a_frame_of_the_wrong_shape_and_leaves_nothing(tmp_path, kind):
    from fuse4d.io import FrameFolderWriter

    k = Intrinsics(30.0, 30.0, 15.5, 11.5, width=32, height=24)
    if kind == "folder":
        writer = FrameFolderWriter(tmp_path / "out", k)
    elif kind == "mkv":
        pytest.importorskip("av")
        from fuse4d.io.video import DepthVideoWriter

        writer = DepthVideoWriter(tmp_path / "out.mkv", k)
    else:
        pytest.importorskip("zarr")
        from fuse4d.io.zarrstore import ZarrWriter

        writer = ZarrWriter(tmp_path / "out.zarr", k)
    bad = r"intensity of frame 1 has shape \(3, 3\), expected \(24, 32\)"

    def write_two_frames() -> None:
        with writer as w:
            w.write(np.full(k.shape, 500.0, np.float32), np.zeros(k.shape, np.float32))
            w.write(np.full(k.shape, 500.0, np.float32), np.zeros((3, 3), np.float32))

    with pytest.raises(ValueError, match=bad):
        write_two_frames()
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("kind", ["folder", "zarr", "npz"])
def test_readers_give_back_the_source_codes_a_fused_output_stores(tmp_path, kind):
    """A fused output's per-pixel source codes (what `fuse4d run` writes beside the depth)
    come back through every layout's ``read_source``, so `fuse4d report` can map them; a
    recording without them gives None."""
    from fuse4d import Sequence
    from fuse4d.io import FrameFolderWriter, open_frames, write_npz

    k = Intrinsics(fx=30.0, fy=30.0, cx=15.5, cy=11.5, width=32, height=24)
    rng = np.random.default_rng(0)
    depth = rng.uniform(500, 900, (3, 24, 32)).astype(np.float32)
    inten = rng.uniform(0, 1, (3, 24, 32)).astype(np.float32)
    source = rng.integers(0, 7, (3, 24, 32)).astype(np.uint8)
    conf = rng.uniform(0, 1, (3, 24, 32)).astype(np.float32)
    if kind == "npz":
        path = tmp_path / "out.npz"
        write_npz(Sequence(depth, inten, k), path, extra={"source": source, "confidence": conf})
        write_npz(Sequence(depth, inten, k), tmp_path / "plain.npz")
        plain = tmp_path / "plain.npz"
    else:
        if kind == "folder":
            path, writer_type = tmp_path / "out", FrameFolderWriter
        else:
            pytest.importorskip("zarr")
            from fuse4d.io.zarrstore import ZarrWriter

            path, writer_type = tmp_path / "out.zarr", ZarrWriter
        plain = tmp_path / f"plain{path.suffix}"
        for dst, flags in ((path, True), (plain, False)):
            with writer_type(dst, k) as w:
                for t in range(3):
                    extra = {"source": source[t], "confidence": conf[t]} if flags else {}
                    w.write(depth[t], inten[t], **extra)
    with open_frames(path) as reader:
        np.testing.assert_array_equal(reader.read_source(1, 3), source[1:3])
    with open_frames(plain) as reader:
        assert reader.read_source(0, 3) is None
