"""Edit operations from a Blender face selection (no bpy: usable and tested outside
Blender). They name input faces, which are the object's polygons in order, so the same
document goes to the service's ``/v1/segment`` (``edits``)."""

from __future__ import annotations

from typing import Any

import numpy as np

#: What each edit button does; the operation's ``op`` in the edit document.
OPERATIONS = ("grow", "shrink", "merge", "paint", "split")


class EditRequestError(ValueError):
    """The selection does not make the asked edit (the message says what to select)."""


def operation(op: str, labels: np.ndarray, selected: np.ndarray, active: int) -> dict[str, Any]:
    """The edit operation ``op`` for per-polygon part ``labels``, the ``selected`` polygons
    (bool per polygon) and the ``active`` polygon (-1: none).

    grow, shrink, split: the part of the active polygon (else the first selected one);
    merge: the parts of all selected polygons become one; paint: the selected polygons
    join the active polygon's part."""
    if op not in OPERATIONS:
        raise EditRequestError(f"unknown edit {op!r}; use one of {', '.join(OPERATIONS)}")
    chosen = np.flatnonzero(np.asarray(selected, dtype=bool) & (np.asarray(labels) >= 0))
    if 0 <= active < len(labels) and labels[active] < 0:
        active = -1
    if op in ("grow", "shrink", "split"):
        face = active if active >= 0 else (int(chosen[0]) if len(chosen) else -1)
        if face < 0:
            raise EditRequestError(f"select a face of the part to {op}")
        return {"op": op, "face": int(face)}
    if op == "merge":
        parts, first = np.unique(np.asarray(labels)[chosen], return_index=True)
        if len(parts) < 2:
            raise EditRequestError("select faces of at least two parts to merge them")
        return {"op": "merge", "faces": sorted(int(f) for f in chosen[first])}
    if active < 0:
        raise EditRequestError("make a face of the part to paint into active (click it last)")
    faces = chosen[np.asarray(labels)[chosen] != labels[active]]
    if len(faces) == 0:
        raise EditRequestError("select faces of other parts to paint into the active face's part")
    return {"op": "paint", "faces": [int(f) for f in faces], "to_face": int(active)}
