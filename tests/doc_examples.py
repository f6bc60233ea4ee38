"""The Python examples of the README and of docs/*.md, found by page and section.

Every ```python block of these pages is run by a test: ``RUN_BY`` names the test that runs the
blocks of each section, and ``tests/test_doc_examples.py`` fails when a block sits in a
section no test runs (a new example must be run as written, or it rots).
"""

from __future__ import annotations

import re
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]

#: (page, section heading) -> the test that runs that section's Python blocks as written.
RUN_BY: dict[tuple[str, str], str] = {
    ("README.md", "Library"): "tests/test_pipeline.py::test_library_examples_run_as_written",
    ("docs/library.md", "Several segmentations of one mesh"): (
        "tests/test_pipeline.py::test_library_examples_run_as_written"
    ),
    ("docs/client.md", "Python client"): (
        "tests/client/test_clients.py::test_client_examples_run_as_written"
    ),
    ("docs/client.md", "Named parts"): (
        "tests/client/test_clients.py::test_named_parts_example_runs_as_written"
    ),
    ("docs/client.md", "Unwrap"): (
        "tests/client/test_unwrapping.py::test_unwrap_example_runs_as_written"
    ),
    ("docs/batch.md", "From Python"): "tests/test_batch.py::test_the_docs_example_runs_as_written",
    ("docs/labeling.md", "Use"): (
        "tests/labeling/test_labeler.py::test_the_docs_example_runs_as_written"
    ),
    ("docs/part-editing.md", "Python"): (
        "tests/client/test_clients.py::test_part_editing_example_runs_as_written"
    ),
}

_FENCE = re.compile(r"^(```|~~~)")
_HEADING = re.compile(r"^#{1,6}\s+(.*?)\s*$")


def pages() -> list[str]:
    """The README and every page under docs/, as paths relative to the repository."""
    docs = sorted(path.name for path in (REPO_ROOT / "docs").glob("*.md"))
    return ["README.md", *(f"docs/{name}" for name in docs)]


def python_blocks_by_section(page: str) -> list[tuple[str, str]]:
    """(nearest heading above it, code) of each ```python block of ``page``, in order.

    Lines inside fences are code: a ``# comment`` there is not a heading.
    """
    blocks: list[tuple[str, str]] = []
    heading = ""
    fence: str | None = None
    language = ""
    code: list[str] = []
    for line in (REPO_ROOT / page).read_text().splitlines():
        if fence is None:
            opened = _FENCE.match(line)
            if opened:
                fence, language, code = opened.group(1), line[3:].strip(), []
            elif match := _HEADING.match(line):
                heading = match.group(1)
        elif line.startswith(fence):
            if language == "python":
                blocks.append((heading, "\n".join(code) + "\n"))
            fence = None
        else:
            code.append(line)
    return blocks


def python_blocks(page: str, section: str) -> list[str]:
    """The ```python blocks under the heading ``section`` of ``page``, in order."""
    assert (page, section) in RUN_BY, f"add ({page!r}, {section!r}) to RUN_BY"
    return [code for heading, code in python_blocks_by_section(page) if heading == section]
