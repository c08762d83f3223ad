"""The pages whose code blocks the tests run: README.md and the manual's Markdown pages.

A block that another test runs is marked ``<!-- NAME:start -->`` ... ``<!-- NAME:end -->``
around its fence; :func:`marked_block` finds it on its page.
"""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"


def pages() -> list[Path]:
    """README.md, then every Markdown page under docs/ (build output left out), sorted."""
    found = sorted(p for p in DOCS.rglob("*.md") if "_build" not in p.relative_to(DOCS).parts)
    return [ROOT / "README.md", *found]


def all_text() -> str:
    """Every page's text, README first: what a reader following them all would type."""
    return "\n".join(p.read_text() for p in pages())


def marked_block(page: str, name: str, lang: str) -> str:
    """The ``lang`` block between the page's ``<!-- NAME:start -->`` and ``:end`` markers."""
    text = (ROOT / page).read_text()
    m = re.search(rf"<!-- {name}:start -->\n```{lang}\n(.*?)```\n<!-- {name}:end -->", text, re.S)
    assert m, f"{page}: the {name} block is missing"
    return m.group(1)
