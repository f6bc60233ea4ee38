"""Every Python example of the README and docs/ is run by a named test (tests/doc_examples.py)."""

from __future__ import annotations

from tests.doc_examples import REPO_ROOT, RUN_BY, pages, python_blocks_by_section


def test_every_python_block_is_in_a_section_a_test_runs():
    unrun = [
        f"{page} under {heading!r}"
        for page in pages()
        for heading, _ in python_blocks_by_section(page)
        if (page, heading) not in RUN_BY
    ]
    assert not unrun, f"Python examples no test runs (add them to RUN_BY): {unrun}"


def test_every_listed_section_has_blocks_and_its_test_exists():
    for (page, section), test in RUN_BY.items():
        assert any(heading == section for heading, _ in python_blocks_by_section(page)), (
            f"{page} has no Python block under {section!r}"
        )
        path, name = test.split("::")
        assert f"def {name}(" in (REPO_ROOT / path).read_text(), f"{test} does not exist"


def test_headings_inside_code_blocks_are_not_sections(tmp_path, monkeypatch):
    import tests.doc_examples as doc_examples

    (tmp_path / "README.md").write_text(
        "# Top\n\n## Library\n\n```python\n# not a heading\nx = 1\n```\n\n"
        "```bash\n# neither\n```\n\n## Other\n\n```python\ny = 2\n```\n"
    )
    monkeypatch.setattr(doc_examples, "REPO_ROOT", tmp_path)
    assert doc_examples.python_blocks_by_section("README.md") == [
        ("Library", "# not a heading\nx = 1\n"),
        ("Other", "y = 2\n"),
    ]
