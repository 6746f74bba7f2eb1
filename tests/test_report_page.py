"""The one renderer of the verification cases' pages (verification/framework/page.py)."""

import re

from verification.framework import page as page_module
from verification.framework.common import Check
from verification.framework.page import Checks, Figure, Heading, Items, Page, Table, Text, page_markdown, write_page


def example():
    return Page("A case", [Text("What ran."), Table(("check", "value"), (("|P - P0|", "1e-15"), ("n", 3))),
                           Heading("Checks"), Checks((Check("|L|", 1e-16, "<=", 1e-12, "round-off"),)),
                           Figure("drift.png", "drift"), Items(()), Items(("one", "two"))])


def test_a_pipe_in_a_cell_is_escaped_and_the_row_keeps_its_cells():
    lines = page_markdown(example()).splitlines()
    row = next(line for line in lines if "P - P0" in line)
    assert row == "| \\|P - P0\\| | 1e-15 |"
    assert len(re.findall(r"(?<!\\)\|", row)) == 3
    assert "| check | value |\n|---|---|\n| \\|P - P0\\| | 1e-15 |\n| n | 3 |" in page_markdown(example())


def test_sections_are_written_in_order_separated_by_blank_lines():
    text = page_markdown(example())
    assert text.startswith("# A case\n\nWhat ran.\n\n| check | value |")
    order = ["# A case", "What ran.", "| check | value |", "## Checks", "| \\|L\\| |", "![drift](drift.png)",
             "(none)", "- one\n- two"]
    positions = [text.index(s) for s in order]
    assert positions == sorted(positions)
    assert text.endswith("- one\n- two\n") and "\n\n\n" not in text


def test_write_page_writes_atomically_and_returns_the_path(tmp_path, monkeypatch):
    written = []

    def spy(path, text):
        written.append(path)
        path.write_text(text)

    monkeypatch.setattr(page_module, "write_text_atomic", spy)
    path = write_page(example(), tmp_path / "case.md")
    assert written == [tmp_path / "case.md"] and path == tmp_path / "case.md"
    assert path.read_text() == page_markdown(example())
    assert [p.name for p in tmp_path.iterdir()] == ["case.md"]  # no temporary file left beside it
