"""Edit operations from a face selection (no bpy): which faces each button names."""

from __future__ import annotations

import numpy as np
import pytest

from blender_addon.part_edits import EditRequestError, operation

LABELS = np.array([0, 0, 1, 1, 2, 2, -1])


def selected(*faces: int) -> np.ndarray:
    chosen = np.zeros(len(LABELS), dtype=bool)
    chosen[list(faces)] = True
    return chosen


def test_tree_edits_take_the_active_face_else_the_first_selected() -> None:
    assert operation("grow", LABELS, selected(2, 4), 4) == {"op": "grow", "face": 4}
    assert operation("shrink", LABELS, selected(3, 5), -1) == {"op": "shrink", "face": 3}
    assert operation("split", LABELS, selected(6, 1), 6) == {"op": "split", "face": 1}
    with pytest.raises(EditRequestError, match="select a face of the part to grow"):
        operation("grow", LABELS, selected(6), -1)  # a face without a part


def test_merge_names_one_face_per_selected_part() -> None:
    assert operation("merge", LABELS, selected(1, 0, 5, 4), -1) == {"op": "merge", "faces": [0, 4]}
    with pytest.raises(EditRequestError, match="at least two parts"):
        operation("merge", LABELS, selected(0, 1), 0)


def test_paint_moves_the_selected_faces_of_other_parts_into_the_active_faces_part() -> None:
    painted = operation("paint", LABELS, selected(0, 2, 3, 6), 0)
    assert painted == {"op": "paint", "faces": [2, 3], "to_face": 0}
    with pytest.raises(EditRequestError, match="active"):
        operation("paint", LABELS, selected(0, 2), -1)
    with pytest.raises(EditRequestError, match="other parts"):
        operation("paint", LABELS, selected(0, 1), 0)
    with pytest.raises(EditRequestError, match="unknown edit"):
        operation("cut", LABELS, selected(0), 0)
