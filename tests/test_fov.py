"""The depth camera's field of view (A38): the row-and-column hull of the valid depth."""

from __future__ import annotations

import numpy as np
import pytest

from fuse4d.fov import _valid_extents, field_of_view


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
