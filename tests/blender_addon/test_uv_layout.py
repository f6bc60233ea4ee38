"""The service's UV layout as a Blender UV map's per-loop values (no bpy)."""

from __future__ import annotations

import base64

import numpy as np
import pytest

from blender_addon.service import ServiceError
from blender_addon.uv_layout import UvLayout, loop_uvs


def layout(counts: list[int]) -> UvLayout:
    corners = sum(counts)
    uvs = np.arange(2 * corners, dtype="<f4").reshape(-1, 2) / (2 * corners)
    body = {
        "faces": len(counts),
        "corner_counts_base64": base64.b64encode(np.array(counts, "<i4").tobytes()).decode(),
        "uvs_base64": base64.b64encode(uvs.tobytes()).decode(),
        "chart_part": [0, 1],
        "utilization": 0.5,
        "split_faces": 0,
    }
    return UvLayout.from_json(body)


def test_loops_take_the_uvs_in_polygon_order() -> None:
    given = layout([4, 3, 5])
    values, missing = loop_uvs(given, np.array([0, 4, 7]), np.array([4, 3, 5]))
    assert missing == 0 and np.array_equal(values, given.uvs)


def test_a_polygon_whose_corners_differ_gets_no_uvs_and_the_others_keep_theirs() -> None:
    given = layout([4, 3, 5])
    values, missing = loop_uvs(given, np.array([0, 4, 6]), np.array([4, 2, 5]))
    assert missing == 1
    np.testing.assert_array_equal(values[:4], given.uvs[:4])
    np.testing.assert_array_equal(values[4:6], 0)
    np.testing.assert_array_equal(values[6:], given.uvs[7:])


def test_a_layout_for_another_mesh_says_to_segment_again() -> None:
    with pytest.raises(ServiceError, match="segment it again"):
        loop_uvs(layout([3, 3]), np.array([0]), np.array([3]))
