"""The pages whose code blocks the tests run: README.md and the manual's Markdown pages.

A block that another test runs is marked ``<!-- NAME:start -->`` ... ``<!-- NAME:end -->``
around its fence; :func:`marked_block` finds it on its page.
"""

from __future__ import annotations

import re
import shlex
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


def commands(code: str) -> list[tuple[list[str], str | None]]:
    """The commands of a bash block as argv lists, each with its heredoc body (or None)."""
    lines = code.replace("\\\n", " ").split("\n")
    out, i = [], 0
    while i < len(lines):
        line = lines[i]
        i += 1
        body = None
        here = re.search(r"<<\s*'?(\w+)'?", line)
        if here:
            end = lines.index(here.group(1), i)
            body, i = "\n".join(lines[i:end]) + "\n", end + 1
            line = line[: here.start()]
        argv = shlex.split(line, comments=True)
        if argv and argv[-1] == "&":
            argv = argv[:-1]
        if argv:
            out.append((argv, body))
    return out
