"""The manual's CLI reference, generated from each command's own parser at build time.

A *command* is what ``python -m NAME`` runs: a package of ``slotv_jax`` with a
``__main__.py``, or a module with an ``if __name__ == "__main__":`` block (:func:`commands`
finds them all by reading the package's files). Its parser is the one its ``main`` really
builds: :func:`parser_of` calls ``main([])`` with :meth:`argparse.ArgumentParser.parse_known_args`
patched to stop at the first parse and hand back the parser, so no option is copied by hand
and nothing else runs. The directive ``command-reference GROUP`` writes one section per
command of the group (``commands``, ``experiments``, ``benchmarks``): its ``--help`` text and
that of each of its sub-commands.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import re
from collections.abc import Iterator
from pathlib import Path

from docutils import nodes
from sphinx.util.docutils import SphinxDirective

PACKAGE = Path(__file__).resolve().parents[2] / "slotv_jax"
GROUPS = ("commands", "experiments", "benchmarks")
_MAIN_BLOCK = re.compile(r'^if __name__ == "__main__":', re.M)


def commands() -> list[str]:
    """Every ``python -m`` name of the package, sorted: packages with a ``__main__.py`` and
    modules with a ``__main__`` block (a package's ``cli`` module that its ``__main__.py``
    runs counts once, as the package)."""
    found = set()
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE.parent).with_suffix("")
        if path.name == "__main__.py":
            found.add(".".join(rel.parts[:-1]))
        elif _MAIN_BLOCK.search(path.read_text()):
            if path.name == "cli.py" and (path.parent / "__main__.py").exists():
                continue
            found.add(".".join(rel.parts))
    return sorted(found)


def group_of(name: str) -> str:
    """``experiments`` or ``benchmarks`` for their commands, else ``commands``."""
    part = name.split(".")[1]
    return part if part in GROUPS else "commands"


class _Parsed(BaseException):  # not an Exception: cli.command lets it through
    def __init__(self, parser: argparse.ArgumentParser):
        self.parser = parser


def _main_of(name: str):
    """The ``main`` that ``python -m NAME`` calls."""
    path = PACKAGE.parent.joinpath(*name.split("."))
    if path.is_dir():
        source = (path / "__main__.py").read_text()
        module = f"{name}.__main__" if _MAIN_BLOCK.search(source) else f"{name}.cli"
    else:
        module = name
    return importlib.import_module(module).main


def parser_of(name: str) -> argparse.ArgumentParser:
    """The parser that the command ``name`` parses its command line with."""
    original = argparse.ArgumentParser.parse_known_args

    def stop(self, args=None, namespace=None):
        raise _Parsed(self)

    argparse.ArgumentParser.parse_known_args = stop
    try:
        _main_of(name)([])
    except _Parsed as parsed:
        return parsed.parser
    finally:
        argparse.ArgumentParser.parse_known_args = original
    raise RuntimeError(f"{name}: main() returned without parsing its command line")


def subparsers(parser: argparse.ArgumentParser) -> Iterator[tuple[str, argparse.ArgumentParser]]:
    """``(name, parser)`` of each sub-command of ``parser``, depth first."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub_name, sub in action.choices.items():
                yield sub_name, sub
                for deeper, p in subparsers(sub):
                    yield f"{sub_name} {deeper}", p


def option_strings(parser: argparse.ArgumentParser) -> set[str]:
    """Every option string (``--out``, ``-h``) of ``parser`` and of its sub-commands."""
    found = {s for a in parser._actions for s in a.option_strings}
    for _, sub in subparsers(parser):
        found |= {s for a in sub._actions for s in a.option_strings}
    return found


@contextlib.contextmanager
def _columns(width: int = 100) -> Iterator[None]:
    old = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = str(width)
    try:
        yield
    finally:
        if old is None:
            os.environ.pop("COLUMNS", None)
        else:
            os.environ["COLUMNS"] = old


def help_texts(name: str) -> list[tuple[str, str]]:
    """``(title, --help text)`` of the command ``name`` and of each of its sub-commands."""
    parser = parser_of(name)
    with _columns():
        texts = [(f"python -m {name}", parser.format_help())]
        texts += [(f"python -m {name} {s}", p.format_help()) for s, p in subparsers(parser)]
    return texts


def anchor(name: str) -> str:
    """The label of a command's section: ``cli-slotv_jax-train``."""
    return "cli-" + name.replace(".", "-")


class CommandReference(SphinxDirective):
    """``command-reference GROUP``: a section per command of GROUP, from its parser."""

    required_arguments = 1

    def run(self) -> list[nodes.Node]:
        group = self.arguments[0]
        if group not in GROUPS:
            raise self.error(f"command-reference: expected one of {GROUPS}, got {group!r}")
        out = []
        for name in (n for n in commands() if group_of(n) == group):
            section = nodes.section(ids=[anchor(name)], names=[anchor(name)])
            section += nodes.title(text=f"python -m {name}")
            for i, (title, text) in enumerate(help_texts(name)):
                if i:
                    section += nodes.rubric(text=title)
                section += nodes.literal_block(text, text, language="text")
            self.state.document.note_explicit_target(section)
            out.append(section)
        return out


def setup(app):
    app.add_directive("command-reference", CommandReference)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
