"""Render a report's tables and plots as ``report.md`` and ``report.html`` (self-contained
apart from the PNGs beside it). Numbers are printed with 3 decimals; the CSV files keep
full precision.
"""

from __future__ import annotations

import html
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd


@dataclass
class Section:
    """One part of the report: a title, a sentence on what it counts, a table and its files."""

    title: str
    text: str
    table: pd.DataFrame | None
    csv: str | None
    plots: Sequence[str] = ()


def _cell(value) -> str:
    if isinstance(value, (float, np.floating)):
        return "" if np.isnan(value) else f"{value:.3f}"
    if value is None or value is pd.NA:
        return ""
    return str(value)


def markdown_table(table: pd.DataFrame) -> str:
    lines = ["| " + " | ".join(table.columns) + " |", "|" + "---|" * len(table.columns)]
    for row in table.itertuples(index=False):
        lines.append("| " + " | ".join(_cell(v).replace("|", "\\|") for v in row) + " |")
    return "\n".join(lines)


def render_markdown(title: str, intro: Sequence[str], sections: Sequence[Section]) -> str:
    parts = [f"# {title}", ""]
    for line in intro:
        parts += [line, ""]
    for section in sections:
        parts += [f"## {section.title}", "", section.text, ""]
        if section.table is not None:
            parts += [markdown_table(section.table), ""]
        if section.csv:
            parts += [f"Table: [{section.csv}]({section.csv})", ""]
        parts += [f"![{section.title}]({plot})" for plot in section.plots]
        if section.plots:
            parts.append("")
    return "\n".join(parts)


STYLE = """
body { font-family: -apple-system, 'Segoe UI', Helvetica, Arial, sans-serif; margin: 24px 40px; color: #222; }
h1 { font-size: 22px; } h2 { font-size: 17px; margin-top: 26px; border-bottom: 1px solid #ddd; }
table { border-collapse: collapse; font-size: 12px; margin: 8px 0; }
th, td { border: 1px solid #ccc; padding: 3px 8px; text-align: right; }
th { background: #f2f4f7; } td:first-child, th:first-child { text-align: left; }
img { max-width: 100%; margin: 6px 12px 6px 0; border: 1px solid #eee; }
p.note { color: #555; font-size: 13px; } .plots { display: flex; flex-wrap: wrap; align-items: flex-start; }
"""


def html_table(table: pd.DataFrame) -> str:
    head = "".join(f"<th>{html.escape(str(c))}</th>" for c in table.columns)
    rows = "".join("<tr>" + "".join(f"<td>{html.escape(_cell(v))}</td>" for v in row) + "</tr>"
                   for row in table.itertuples(index=False))
    return f"<table><thead><tr>{head}</tr></thead><tbody>{rows}</tbody></table>"


def render_html(title: str, intro: Sequence[str], sections: Sequence[Section]) -> str:
    body = [f"<h1>{html.escape(title)}</h1>"] + [f"<p class='note'>{html.escape(line)}</p>" for line in intro]
    for section in sections:
        body.append(f"<h2>{html.escape(section.title)}</h2><p class='note'>{html.escape(section.text)}</p>")
        if section.plots:
            body.append("<div class='plots'>" + "".join(
                f"<img src='{html.escape(p)}' alt='{html.escape(section.title)}'>" for p in section.plots) + "</div>")
        if section.table is not None:
            body.append(html_table(section.table))
        if section.csv:
            link = html.escape(section.csv)
            body.append(f"<p class='note'>Table: <a href='{link}'>{link}</a></p>")
    return (f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
            f"<style>{STYLE}</style></head><body>{''.join(body)}</body></html>\n")


def write_documents(out: Path, title: str, intro: Sequence[str], sections: Sequence[Section]) -> tuple[Path, Path]:
    md, page = out / "report.md", out / "report.html"
    md.write_text(render_markdown(title, intro, sections))
    page.write_text(render_html(title, intro, sections))
    return md, page


__all__ = ["Section", "markdown_table", "render_markdown", "render_html", "write_documents"]
