"""The depth camera's field of view (A38): the row-and-column hull of the valid depth."""

from __future__ import annotations

import numpy as np
import pytest

from fuse4d._kernels.fov import _inside_extents_kernel, _valid_extents_kernel
from fuse4d.fov import _inside_extents, _valid_extents, field_of_view


def _hull_reference(depth):
    """field_of_view by its definition, pixel by pixel: valid depth in some frame at or on
    both sides of the pixel along its row, and likewise along its column."""
    valid = (np.nan_to_num(depth, nan=0.0) > 0).any(axis=0)
    h, w = valid.shape
    out = np.zeros((h, w), bool)
    for v in range(h):
        for u in range(w):
            row, col = valid[v], valid[:, u]
            out[v, u] = (
                row[: u + 1].any() and row[u:].any() and col[: v + 1].any() and col[v:].any()
            )
    return out


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_field_of_view_is_the_row_and_column_hull_of_the_valid_depth(seed):
    rng = np.random.default_rng(seed)
    depth = rng.uniform(500, 3000, (3, 17, 23)).astype(np.float32)
    depth[rng.random(depth.shape) < 0.6] = np.nan
    depth[rng.random(depth.shape) < 0.1] = 0.0  # 0 = no depth, as in 16-bit files
    depth[:, :2] = np.nan  # a band without depth at the top ...
    depth[:, :, -3:] = 0.0  # ... and on the right
    inside = field_of_view(depth)
    np.testing.assert_array_equal(inside, _hull_reference(depth))
    assert not inside[:2].any()
    assert not inside[:, -3:].any()
    np.testing.assert_array_equal(field_of_view(depth[1]), _hull_reference(depth[1:2]))


def test_valid_extents_of_an_empty_row_and_column():
    d = np.full((4, 5), np.nan, np.float32)
    d[1, 2] = d[2, 3] = 1000.0
    rows, cols = _valid_extents(d)
    assert rows.tolist() == [[5, -1], [2, 2], [3, 3], [5, -1]]
    assert cols.tolist() == [[4, -1], [4, -1], [1, 1], [2, 2], [4, -1]]


@pytest.mark.parametrize("seed", [0, 1])
def test_engine_kernels_equal_the_numpy_extents_and_hull(seed):
    """The engine's kernels (one pass each) give the values of the numpy forms (their
    oracle): per-frame extents, empty rows, columns and frames included, and the hull of a
    window of ring slots in any order."""
    rng = np.random.default_rng(seed)
    depth = rng.uniform(500, 3000, (5, 17, 23)).astype(np.float32)
    depth[rng.random(depth.shape) < 0.7] = np.nan
    depth[1, 3] = np.nan  # an empty row
    depth[2, :, 5] = np.nan  # an empty column
    depth[4] = np.nan  # a frame without depth
    rows = np.zeros((5, 17, 2), np.int32)
    cols = np.zeros((5, 23, 2), np.int32)
    for k in range(5):
        _valid_extents_kernel(depth[k], rows[k], cols[k])
        r, c = _valid_extents(depth[k])
        np.testing.assert_array_equal(rows[k], r)
        np.testing.assert_array_equal(cols[k], c)
    for slots in ([0], [4], [3, 4, 0, 1], [2, 1]):
        frame_slot = np.array(slots, np.int64)
        inside = np.empty((17, 23), bool)
        _inside_extents_kernel(rows, cols, frame_slot, inside)
        np.testing.assert_array_equal(inside, _inside_extents(rows[frame_slot], cols[frame_slot]))
        np.testing.assert_array_equal(inside, field_of_view(depth[frame_slot]))
