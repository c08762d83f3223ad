"""Every ``>>>`` example in the package's docstrings runs, module by module, with the
suite's environment (``conftest.py``: the OpenGL backend, the shared compilation cache).
Float output is compared with ``NORMALIZE_WHITESPACE`` and ``ELLIPSIS``; an example that
needs what a test machine lacks (a GPU, a browser, files of its own) says
``# doctest: +SKIP``."""

from __future__ import annotations

import doctest
import importlib
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "slotv_jax"
FLAGS = doctest.NORMALIZE_WHITESPACE | doctest.ELLIPSIS


def modules_with_examples() -> list[str]:
    """Every module of the package whose source holds a ``>>>`` line (``__main__`` files
    run a command when imported: they hold none)."""
    names = []
    for path in sorted(PACKAGE.rglob("*.py")):
        if path.name != "__main__.py" and ">>>" in path.read_text():
            parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
            names.append(".".join(parts[:-1] if parts[-1] == "__init__" else parts))
    return names


def test_examples_are_found():
    names = modules_with_examples()
    assert "slotv_jax.observers.prefix" in names and "slotv_jax.core.cli" in names
    assert len(names) >= 50


@pytest.mark.parametrize("name", modules_with_examples())
def test_docstring_examples_run(name, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # an example that writes a file writes it here
    module = importlib.import_module(name)
    finder = doctest.DocTestFinder(exclude_empty=True)
    runner = doctest.DocTestRunner(optionflags=FLAGS)
    tests = [t for t in finder.find(module, name) if t.examples]
    assert tests, f"{name}: a '>>>' line that doctest does not find (not in a docstring?)"
    report: list[str] = []
    for test in tests:
        runner.run(test, out=report.append)
    failed, attempted = runner.summarize(verbose=False)
    assert failed == 0, f"{name}: {failed} of {attempted} examples failed\n" + "".join(report)
