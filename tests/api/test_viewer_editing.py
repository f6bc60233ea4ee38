"""The viewer's editing.js (run by Node) gives the labels of ``segment.editing`` for the
same trees and documents: the page and the service agree without a request."""

from __future__ import annotations

import json
import shutil
import subprocess

import numpy as np
import pytest

from neural_shdf.api.viewer import VIEWER_DIR
from neural_shdf.segment.editing import EditError, apply_edits, apply_label_edits
from neural_shdf.segment.hierarchy import PartTree

NODE = shutil.which("node")
pytestmark = pytest.mark.skipif(NODE is None, reason="node is not installed")

RUNNER = """
import { applyEdits, applyLabelEdits, extendEdits } from '%s';
const cases = JSON.parse(process.argv[2]);
const apply = (c, edits) => (c.tree
  ? applyEdits(c.tree, Int32Array.from(c.leaves), c.parts, edits)
  : applyLabelEdits(Int32Array.from(c.leaves), edits));
const out = cases.map((c) => {
  try {
    if (!c.stepwise) return Array.from(apply(c, c.edits).labels);
    // As the page edits: the first operation applied, each later one added to its state.
    let result = apply(c, c.edits.slice(0, 1));
    const steps = [Array.from(result.labels)];
    for (let n = 2; n <= c.edits.length; n++) {
      result = extendEdits(result, c.edits.slice(0, n));
      steps.push(Array.from(result.labels));
    }
    return steps;
  } catch (error) {
    return { error: error.message };
  }
});
console.log(JSON.stringify(out));
"""


def random_tree(rng: np.random.Generator, leaves: int) -> np.ndarray:
    alive = list(range(leaves))
    merges = []
    for node in range(leaves, 2 * leaves - 1):
        a, b = sorted(rng.choice(len(alive), 2, replace=False).tolist(), reverse=True)
        merges.append(sorted((alive.pop(a), alive.pop(b))))
        alive.append(node)
    return np.array(merges, dtype=np.int64).reshape(-1, 2)


def random_document(rng: np.random.Generator, faces: int, count: int) -> list[dict]:
    document = []
    for _ in range(count):
        op = str(rng.choice(["grow", "shrink", "merge", "paint"]))
        pick = lambda n: rng.integers(0, faces, n).tolist()  # noqa: E731
        if op in ("grow", "shrink"):
            document.append({"op": op, "face": pick(1)[0]})
        elif op == "merge":
            document.append({"op": op, "faces": pick(int(rng.integers(1, 4)))})
        else:
            document.append(
                {"op": op, "faces": pick(int(rng.integers(1, 6))), "to_face": pick(1)[0]}
            )
    return document


def run_node(tmp_path, cases: list[dict]) -> list:
    script = tmp_path / "run.mjs"
    script.write_text(RUNNER % (VIEWER_DIR / "static" / "editing.js").as_uri())
    done = subprocess.run(
        [NODE, str(script), json.dumps(cases)], capture_output=True, text=True, check=True
    )
    return json.loads(done.stdout)


def test_page_edits_equal_the_librarys(tmp_path):
    rng = np.random.default_rng(11)
    cases, expected = [], []
    for index in range(60):
        leaves = int(rng.integers(1, 25))
        merges = random_tree(rng, leaves)
        faces = np.concatenate([np.arange(leaves), rng.integers(0, leaves, 30)])
        if index % 5 == 0:
            faces[rng.integers(0, len(faces), 3)] = -1  # faces without triangles
        tree = PartTree(faces, merges, np.zeros(leaves - 1))
        parts = int(rng.integers(1, leaves + 1))
        document = random_document(rng, len(faces), int(rng.integers(0, 12)))
        with_tree = index % 4 != 0
        leaf_input = faces if with_tree else tree.relabel(faces, parts)
        if not with_tree:
            document = [e for e in document if e["op"] in ("merge", "paint")]
        try:
            labels = (
                apply_edits(tree, faces, parts, document)
                if with_tree
                else apply_label_edits(leaf_input, document)
            )
            expected.append(labels.tolist())
        except EditError:
            expected.append("error")
        cases.append(
            {
                "tree": {"leaf_count": leaves, "parent": tree.parent.tolist()}
                if with_tree
                else None,
                "leaves": leaf_input.tolist(),
                "parts": parts,
                "edits": document,
            }
        )
    got = run_node(tmp_path, cases)
    for case, mine, theirs in zip(cases, got, expected, strict=True):
        if theirs == "error":
            assert isinstance(mine, dict) and "error" in mine, case
        else:
            assert mine == theirs, case
    assert sum(e != "error" for e in expected) > 30


def test_page_refuses_what_the_service_refuses(tmp_path):
    tree = {"leaf_count": 2, "parent": [2, 2, -1]}
    cases = [
        {"tree": tree, "leaves": [0, 1], "parts": 2, "edits": [{"op": "grow", "face": 2}]},
        {"tree": tree, "leaves": [0, 1], "parts": 2, "edits": [{"op": "split", "face": 0}]},
        {"tree": None, "leaves": [0, 1], "parts": 2, "edits": [{"op": "grow", "face": 0}]},
    ]
    messages = [result["error"] for result in run_node(tmp_path, cases)]
    assert "face 2 is out of range" in messages[0]
    assert "unknown op" in messages[1]
    assert "needs the part tree" in messages[2]


def test_edits_added_one_at_a_time_equal_the_whole_document_applied(tmp_path):
    """The page adds each new operation to its edit state (``extendEdits``) instead of
    applying the whole document again: the labels after every step are the library's."""
    rng = np.random.default_rng(5)
    cases, expected = [], []
    while len(cases) < 40:
        leaves = int(rng.integers(2, 25))
        merges = random_tree(rng, leaves)
        faces = np.concatenate([np.arange(leaves), rng.integers(0, leaves, 30)])
        tree = PartTree(faces, merges, np.zeros(leaves - 1))
        parts = int(rng.integers(1, leaves + 1))
        document = random_document(rng, len(faces), int(rng.integers(1, 12)))
        with_tree = len(cases) % 4 != 0
        leaf_input = faces if with_tree else tree.relabel(faces, parts)
        if not with_tree:
            document = [e for e in document if e["op"] in ("merge", "paint")] or [
                {"op": "merge", "faces": [0, 1]}
            ]
        steps = [
            (
                apply_edits(tree, faces, parts, document[:n])
                if with_tree
                else apply_label_edits(leaf_input, document[:n])
            ).tolist()
            for n in range(1, len(document) + 1)
        ]
        expected.append(steps)
        cases.append(
            {
                "tree": {"leaf_count": leaves, "parent": tree.parent.tolist()}
                if with_tree
                else None,
                "leaves": leaf_input.tolist(),
                "parts": parts,
                "edits": document,
                "stepwise": True,
            }
        )
    got = run_node(tmp_path, cases)
    for case, mine, theirs in zip(cases, got, expected, strict=True):
        assert mine == theirs, case
    assert sum(len(steps) for steps in expected) > 150
