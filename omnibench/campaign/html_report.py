"""report.html beside report.md: the same report as one self-contained file for a browser.

The Markdown is rendered with markdown-it-py (CommonMark plus tables; it comes with `rich`),
and every plot it links is embedded as a base64 data URI, so the file can be mailed or archived
on its own.
"""

from __future__ import annotations

import base64
import html
import mimetypes
from pathlib import Path

STYLE = """
body { font-family: system-ui, sans-serif; max-width: 70rem; margin: 2rem auto; padding: 0 1rem;
       color: #1d1d1f; line-height: 1.45; }
h1 { border-bottom: 2px solid #ccc; padding-bottom: .3rem; }
h2 { margin-top: 2rem; border-bottom: 1px solid #ddd; }
table { border-collapse: collapse; margin: .6rem 0; font-size: .92rem; }
th, td { border: 1px solid #ccc; padding: .25rem .55rem; text-align: left; font-variant-numeric: tabular-nums; }
th { background: #f2f2f4; }
tr:nth-child(even) td { background: #fafafa; }
code { background: #f2f2f4; padding: 0 .2rem; border-radius: 3px; font-size: .9em; }
img { max-width: 100%; border: 1px solid #eee; margin: .5rem 0; }
"""


def _inline(src: str, base: Path) -> str:
    """`src` as a data URI when it names a readable local file, else unchanged."""
    if src.startswith(("data:", "http:", "https:")):
        return src
    path = (base / src).resolve()
    try:
        data = path.read_bytes()
    except OSError:
        return src
    mime = mimetypes.guess_type(path.name)[0] or "application/octet-stream"
    return f"data:{mime};base64,{base64.b64encode(data).decode('ascii')}"


def markdown_to_html(text: str, base: Path, title: str) -> str:
    """A complete HTML page for Markdown `text`, images under `base` inlined."""
    from markdown_it import MarkdownIt

    md = MarkdownIt("commonmark", {"html": True}).enable("table")
    tokens = md.parse(text)
    for tok in tokens:
        for child in tok.children or []:
            if child.type == "image":
                child.attrSet("src", _inline(str(child.attrGet("src") or ""), base))
    body = md.renderer.render(tokens, md.options, {})
    return (f"<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"
            f"<title>{html.escape(title)}</title><style>{STYLE}</style></head>\n<body>\n{body}</body></html>\n")


def write_html(report_md: Path) -> Path:
    """Write report.html next to `report_md` (one file, plots inline); returns its path."""
    report_md = Path(report_md)
    out = report_md.with_suffix(".html")
    text = report_md.read_text(encoding="utf-8")
    title = next((ln[2:].strip() for ln in text.splitlines() if ln.startswith("# ")), "omnibench report")
    out.write_text(markdown_to_html(text, report_md.parent, title), encoding="utf-8")
    return out
