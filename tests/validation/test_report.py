"""The Markdown report keeps the hand-written text around its generated block."""

from __future__ import annotations

from mavattitude.validation.report import BEGIN, END, write_markdown


def test_write_markdown_replaces_only_the_generated_block(tmp_path) -> None:
    doc = tmp_path / "validation.md"
    write_markdown(doc, "first tables")
    assert doc.read_text().startswith("# Validation on real sensor data") and "first tables" in doc.read_text()
    doc.write_text("# Title\n\nanalysis before\n\n" + doc.read_text().split("\n", 2)[2] + "\nanalysis after\n")
    write_markdown(doc, "second tables")
    text = doc.read_text()
    assert "first tables" not in text and "second tables" in text
    assert text.index("analysis before") < text.index(BEGIN) < text.index("second tables") < text.index(END)
    assert text.index(END) < text.index("analysis after")
