"""The manual covers the package: every public module has an API page, and the CLI
reference (generated from the parsers by ``docs/_ext/cliref.py`` at build time) holds every
command and every option. The build itself, with warnings as errors, runs in ``.ci/run``."""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
sys.path.insert(0, str(DOCS / "_ext"))

import apiref  # noqa: E402
import cliref  # noqa: E402

_AUTOMODULE = re.compile(r"^\.\. automodule:: (\S+)", re.M)


def _api_pages() -> dict[str, list[str]]:
    """Module -> the API pages whose ``automodule`` documents it."""
    pages: dict[str, list[str]] = {}
    for page in sorted((DOCS / "api").glob("*.md")):
        for module in _AUTOMODULE.findall(page.read_text()):
            pages.setdefault(module, []).append(page.name)
    return pages


def test_every_public_module_has_one_api_page():
    modules = apiref.public_modules()
    # the scan sees the package's layers, commands and aliases (an independent sample)
    for name in ("slotv_jax", "slotv_jax.robot.kinematics", "slotv_jax.kinematics",
                 "slotv_jax.experiments.table1", "slotv_jax.webstudy.server"):  # fmt: skip
        assert name in modules
    assert not any("._" in m for m in modules)
    pages = _api_pages()
    missing = [m for m in modules if m not in pages]
    assert not missing, f"public modules without an API page (docs/api/*.md): {missing}"
    twice = {m: p for m, p in pages.items() if len(p) > 1}
    assert not twice, f"modules documented on more than one API page: {twice}"
    unknown = sorted(set(pages) - set(modules))
    assert not unknown, f"API pages document modules that are not public: {unknown}"


def test_commands_are_found_by_reading_the_package():
    found = cliref.commands()
    mains = sorted(
        ".".join(p.relative_to(ROOT).with_suffix("").parts[:-1])
        for p in (ROOT / "slotv_jax").rglob("__main__.py")
    )
    assert set(mains) <= set(found)
    for name in ("slotv_jax.train", "slotv_jax.study", "slotv_jax.experiments.table1",
                 "slotv_jax.benchmarks.training", "slotv_jax.data.report"):  # fmt: skip
        assert name in found
    assert "slotv_jax.train.cli" not in found  # what `python -m slotv_jax.train` runs


def test_every_command_group_has_its_cli_page():
    groups = {cliref.group_of(n) for n in cliref.commands()}
    assert groups == set(cliref.GROUPS)
    for group in cliref.GROUPS:
        text = (DOCS / "cli" / f"{group}.md").read_text()
        assert f"```{{command-reference}} {group}\n```" in text
        assert group in (DOCS / "cli" / "index.md").read_text()


@pytest.mark.parametrize("name", cliref.commands())
def test_cli_reference_shows_every_option(name):
    """The text the CLI page shows for ``name`` holds every option of the parser its
    ``main`` parses with, and of each sub-command (all but the ones hidden from --help)."""
    parser = cliref.parser_of(name)
    assert isinstance(parser, argparse.ArgumentParser)
    shown = "\n".join(text for _, text in cliref.help_texts(name))
    parsers = [parser, *(p for _, p in cliref.subparsers(parser))]
    options = {
        s for p in parsers for a in p._actions if a.help != argparse.SUPPRESS
        for s in a.option_strings
    }  # fmt: skip
    assert "-h" in options
    missing = sorted(s for s in options if not re.search(rf"(?<![\w-]){re.escape(s)}\b", shown))
    assert not missing, f"python -m {name}: options the manual does not show: {missing}"
    for sub, _ in cliref.subparsers(parser):
        assert f"python -m {name} {sub}" in [title for title, _ in cliref.help_texts(name)]
