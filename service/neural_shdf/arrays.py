"""Array operations the service runs beside its event loop, written so that numpy can
release the GIL while they sort.

``np.unique(rows, axis=0)`` sorts the rows as one structured value each, a comparison that
holds the GIL for the whole sort (seconds on an unwrapped mesh's corners, during which the
service answers nothing); ``np.lexsort`` sorts column by column with the GIL released.
"""

from __future__ import annotations

import json
from typing import Any, overload

import numpy as np
from numpy.typing import NDArray


def _row_order(rows: NDArray[Any]) -> tuple[NDArray[np.int64], NDArray[np.bool_]]:
    """The stable lexicographic order of the rows, and in that order where a new distinct
    row starts."""
    order = np.lexsort(rows.T[::-1]) if rows.shape[1] else np.arange(len(rows))
    ordered = rows[order]
    starts = np.ones(len(rows), dtype=bool)
    if len(rows) > 1:
        starts[1:] = np.any(ordered[1:] != ordered[:-1], axis=1)
    return order.astype(np.int64, copy=False), starts


@overload
def unique_rows(rows: NDArray[Any]) -> NDArray[Any]: ...
@overload
def unique_rows(
    rows: NDArray[Any],
    *,
    return_index: bool = ...,
    return_inverse: bool = ...,
    return_counts: bool = ...,
) -> NDArray[Any] | tuple[NDArray[Any], ...]: ...
def unique_rows(
    rows: NDArray[Any],
    *,
    return_index: bool = False,
    return_inverse: bool = False,
    return_counts: bool = False,
) -> NDArray[Any] | tuple[NDArray[Any], ...]:
    """``np.unique(rows, axis=0, ...)`` for a 2-D array: the distinct rows in lexicographic
    order, then, as asked, the index of each one's first occurrence, the distinct row of
    every input row, and how often each occurs."""
    rows = np.asarray(rows)
    if rows.ndim != 2:
        raise ValueError(f"unique_rows takes a 2-D array, got {rows.ndim} dimensions")
    order, starts = _row_order(rows)
    first_in_order = np.flatnonzero(starts)
    unique = rows[order[first_in_order]]
    extra: list[NDArray[Any]] = []
    if return_index:
        extra.append(order[first_in_order])
    if return_inverse:
        inverse = np.empty(len(rows), dtype=np.int64)
        inverse[order] = np.cumsum(starts) - 1
        extra.append(inverse)
    if return_counts:
        extra.append(np.diff(np.append(first_in_order, len(rows))).astype(np.int64))
    return (unique, *extra) if extra else unique


#: Values encoded per step by ``json_array``: each step is one short C call.
JSON_CHUNK = 1 << 13


def json_array(values: NDArray[Any], *, nan_as_null: bool = False) -> str:
    """A 1-D array as a compact JSON array, the same text as ``json.dumps(values.tolist(),
    separators=(",", ":"))`` (with ``nan_as_null``, NaN as ``null``), encoded a chunk at a
    time: one ``json.dumps`` of a million-element list holds the GIL for a tenth of a
    second or more, and the service encodes its answers beside its event loop."""
    flat = np.asarray(values).reshape(-1)
    pieces = []
    for start in range(0, len(flat), JSON_CHUNK):
        chunk = flat[start : start + JSON_CHUNK].tolist()
        if nan_as_null:
            chunk = [None if value != value else value for value in chunk]
        pieces.append(json.dumps(chunk, separators=(",", ":"))[1:-1])
    return "[" + ",".join(pieces) + "]"


def json_list(items: list[Any], *, chunk: int = 2048) -> str:
    """A list of JSON-ready objects (e.g. one dict per part) as compact JSON, the same text as
    ``json.dumps(items, separators=(",", ":"))``, encoded ``chunk`` items at a time: the C
    encoder holds the GIL for the whole list (100,000 parts: over 0.1 s)."""
    pieces = [
        json.dumps(items[start : start + chunk], separators=(",", ":"))[1:-1]
        for start in range(0, len(items), chunk)
    ]
    return "[" + ",".join(pieces) + "]"
