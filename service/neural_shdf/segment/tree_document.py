"""The part tree as a JSON document (the API's ``hierarchy``, the CLI's ``--tree``)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from neural_shdf.segment.hierarchy import PartTree, automatic_part_count


def part_tree_document(
    tree: PartTree, leaf_labels: NDArray[Any], parts: int, *, as_arrays: bool = False
) -> dict[str, Any]:
    """The part tree as JSON-ready data (the API's ``hierarchy`` and the CLI's ``--tree``).

    ``leaf_labels``: leaf per face of the output (e.g. per input face; -1 for none).
    Keys: ``leaf_count`` L; ``parts`` (the count the labels were cut at);
    ``automatic_parts``; ``leaf_labels``; ``parent`` (2L - 1 node ids, -1 for the
    root; leaves are 0..L-1, merge i made node L + i); ``merge_cost`` and
    ``merge_height`` (L - 1; height: running maximum of the cost). To cut at N
    parts, give each leaf its highest ancestor with id < 2L - N (itself when its
    parent's id is >= 2L - N) and number the parts by their smallest leaf.
    ``as_arrays``: the four arrays as numpy arrays (for ``arrays.json_array``), not lists.
    """
    document: dict[str, Any] = {
        "leaf_count": tree.leaf_count,
        "parts": int(parts),
        "automatic_parts": automatic_part_count(tree),
        "leaf_labels": np.asarray(leaf_labels, dtype=np.int64),
        "parent": np.asarray(tree.parent, dtype=np.int64),
        "merge_cost": np.asarray(tree.costs, dtype=np.float64),
        "merge_height": np.asarray(tree.heights, dtype=np.float64),
    }
    if not as_arrays:
        for key in ("leaf_labels", "parent", "merge_cost", "merge_height"):
            document[key] = document[key].tolist()
    return document


def write_part_tree(
    path: str | Path, tree: PartTree, leaf_labels: NDArray[Any], parts: int
) -> None:
    """Write ``part_tree_document`` as a JSON file."""
    Path(path).write_text(json.dumps(part_tree_document(tree, leaf_labels, parts)))
