"""Tables as HTML and as escaped Markdown: the one place the report turns a table into text."""

from __future__ import annotations

import html

import pandas as pd

__all__ = ["html_table", "markdown_table"]


def html_table(df: pd.DataFrame | None, *, text: bool = False, digits: int = 3) -> str:
    """An HTML table of ``df`` (a note when it has no rows).

    ``text`` left-aligns every column (tables of messages); floats are shown with
    ``digits`` significant digits, missing values as ``-``; cells are escaped.
    """
    if df is None or df.empty:
        return '<p class="note">(no rows)</p>'
    return df.to_html(index=False, escape=True, na_rep="-", border=0,
                      classes="text" if text else None,
                      float_format=lambda v: f"{v:.{digits}g}")


def _md_cell(value) -> str:
    """A Markdown table cell that renders as the text it holds, never as HTML or markup.

    ``<``, ``>``, ``&`` and quotes become HTML entities (a ``<script>`` in a plugin's
    message stays text), ``|`` is escaped so it cannot split the cell, and line breaks
    become spaces so they cannot end the row.
    """
    text = html.escape(str(value), quote=True).replace("|", "\\|")
    return " ".join(text.splitlines())


def markdown_table(df: pd.DataFrame | None) -> str:
    """``df`` as a Markdown table with every header and cell escaped (:func:`_md_cell`)."""
    if df is None or df.empty:
        return "(no rows)\n"
    shown = df.copy()
    for col in shown.columns:
        if not pd.api.types.is_numeric_dtype(shown[col]):
            shown[col] = shown[col].map(lambda v: v if pd.isna(v) else _md_cell(v))
    shown.columns = [_md_cell(c) for c in shown.columns]
    return shown.to_markdown(index=False) + "\n"
