"""Builders of the part-edit document that ``Client.segment(..., edits=...)`` sends.

Operations name input faces (the file's face order), not tree nodes, so a document
still applies after a re-segmentation with other options::

    from neural_shdf.client import edits

    document = [edits.grow(120), edits.merge(120, 4031), edits.paint([7, 8, 9], to_face=4031)]
    parts = client.segment(mesh_id, parts=6, edits=document)

The same document can be applied locally to a response's tree:
``segmentation.hierarchy.edited(document)``.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any


def grow(face: int) -> dict[str, Any]:
    """The part-tree node holding ``face`` becomes its parent (no-op at the root)."""
    return {"op": "grow", "face": int(face)}


def shrink(face: int) -> dict[str, Any]:
    """The part-tree node holding ``face`` splits into its two children (no-op at a leaf)."""
    return {"op": "shrink", "face": int(face)}


def merge(*faces: int) -> dict[str, Any]:
    """The parts holding ``faces`` become one."""
    return {"op": "merge", "faces": [int(face) for face in faces]}


def paint(faces: Iterable[int], to_face: int) -> dict[str, Any]:
    """``faces`` join the part holding ``to_face``."""
    return {"op": "paint", "faces": [int(face) for face in faces], "to_face": int(to_face)}


def split(face: int) -> dict[str, Any]:
    """The part holding ``face`` is bisected (METIS); the half without ``face`` is a new
    part. Needs the mesh, so only the service applies it (not ``PartHierarchy.edited``)."""
    return {"op": "split", "face": int(face)}


__all__ = ["grow", "merge", "paint", "shrink", "split"]
