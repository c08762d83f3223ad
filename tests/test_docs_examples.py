"""Every fenced code block of README.md and docs/**/*.md runs, or is parsed, here.

The rule. A block's language is one of ``python``, ``bash``, ``json`` or ``bibtex``; the
comment on the line before its fence, if any, says what is done with it:

- no comment: ``python`` is executed, ``bash`` is parsed (below), ``json`` is loaded;
- ``<!-- docs: run -->``: a ``bash`` block executed (``bash -e``), for cheap commands;
- ``<!-- docs: parse-only -->``: an expensive block (paper presets, hour-long runs, GPUs,
  servers, the set-up itself): ``bash`` parsed; ``python`` compiled and its imports run;
- ``<!-- docs: external -->``: a block for software outside slotv_jax (ROS 2, panda-py):
  ``python`` compiled, ``bash`` checked by ``bash -n``;
- ``<!-- docs: system -->``: the ``apt-get install`` line, whose packages must be those
  ``.ci/run`` installs;
- ``<!-- docs: bibtex -->``: the paper's BibTeX, which must agree with ``CITATION.cff``;
- ``<!-- NAME:start -->`` (closed by ``<!-- NAME:end -->``): a block that another test runs
  (``tests/docs_pages.marked_block``); the named test must exist, and ``bash`` is parsed
  here too.

*Parsed* means: every ``python -m slotv_jax...`` command of the block (continuation lines
joined, comments dropped) is run as ``python -m`` runs it, up to its own argparse parser,
which validates every flag and value and then stops the command before any work; so a
renamed command or flag, or a value not among a flag's choices, fails this test. The bodies
of ``python - <<'EOF'`` heredocs are compiled and their imports run; ``pip install`` and
``python -m pytest`` must be what ``.ci/run`` runs; ``sphinx-build`` goes through Sphinx's
own parser. Any other command must be one of a few shell words (``cat``, ``kill``,
``export``, ``server=$!``). A block that is neither run nor parsed cannot exist: an
unknown language, mode or command fails.

The python blocks of a page share one namespace and run in order, in a temporary folder
of their own, as a reader would run them; ``run`` blocks run in that folder too, so a later
block finds an earlier one's files. There, ``data/`` holds the suite's tiny dataset under
the quick preset's name (``--data quick``, ``load_split("quick", ...)``) and
``experiments/`` is the repository's records (read only).
"""

from __future__ import annotations

import argparse
import ast
import contextlib
import io
import json
import os
import re
import runpy
import shlex
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from docs_pages import ROOT, commands, pages

from slotv_jax import data

LANGS = {"python", "bash", "json", "bibtex"}
MODES = {"run", "parse-only", "external", "system", "bibtex"}
SHELL_WORDS = {"cat", "kill", "export"}
FENCE = re.compile(r"^```(\S*)[^\n]*\n(.*?)^```\n", re.S | re.M)  # ```{directive} arg
COMMENT = re.compile(r"<!-- (?:docs: (\S+)|([\w-]+):start) -->\n$")


class Parsed(BaseException):
    """Raised by the patched parse_args once a command's parser accepted its arguments."""


def blocks(page: Path) -> list[tuple[int, str, str, str]]:
    """(line, language, mode, code) of every fenced block of ``page``, in order."""
    text = page.read_text()
    out = []
    for m in FENCE.finditer(text):
        before = text[: m.start()]
        line = before.count("\n") + 1
        last = before.rsplit("\n", 2)
        comment = COMMENT.search(last[-2] + "\n") if len(last) >= 2 else None
        lang = m.group(1)
        if lang.startswith("{"):  # a MyST directive (toctree, include), not code
            continue
        mode = "default"
        if comment:
            mode = comment.group(1) or f"marked:{comment.group(2)}"
        out.append((line, lang, mode, m.group(2)))
    return out


def page_id(page: Path) -> str:
    return str(page.relative_to(ROOT))


PAGES = pages()


def test_every_block_has_a_known_language_and_mode():
    """The rule of this module's docstring holds for every block of every page."""
    seen = 0
    for page in PAGES:
        for line, lang, mode, _ in blocks(page):
            where = f"{page_id(page)}:{line}"
            assert lang in LANGS, f"{where}: a ```{lang} block (expected one of {sorted(LANGS)})"
            assert mode == "default" or mode.startswith("marked:") or mode in MODES, where
            if mode == "run":
                assert lang == "bash", f"{where}: docs: run is for bash blocks"
            if mode in ("system", "bibtex"):
                assert lang == ("bash" if mode == "system" else "bibtex"), where
            if lang == "bibtex":
                assert mode == "bibtex", f"{where}: a bibtex block needs <!-- docs: bibtex -->"
            seen += 1
    assert seen >= 30, seen


def test_marked_blocks_are_run_by_their_test():
    """A block marked NAME:start is run by a test that names it (and the marker closes)."""
    tests = "\n".join(
        p.read_text() for p in (ROOT / "tests").glob("test_*.py") if p.name != Path(__file__).name
    )
    for page in PAGES:
        text = page.read_text()
        for line, _, mode, _ in blocks(page):
            if mode.startswith("marked:"):
                name = mode.split(":", 1)[1]
                assert f"<!-- {name}:end -->" in text, f"{page_id(page)}:{line}: {name} not closed"
                assert f'"{name}"' in tests, f"{page_id(page)}:{line}: no test runs {name}"


# ----------------------------------------------------------------- parsing commands


def ci_lines() -> list[str]:
    return (ROOT / ".ci" / "run").read_text().splitlines()


def run_parser(argv: list[str], where: str) -> argparse.Namespace:
    """Run ``python -m MODULE ARGS`` up to its parser's parse_args; its Namespace."""
    module, args = argv[2], argv[3:]
    original = argparse.ArgumentParser.parse_args

    def parse_args(self, args=None, namespace=None):
        ns = original(self, args, namespace)
        raise Parsed(ns)

    err = io.StringIO()
    old_argv = sys.argv
    argparse.ArgumentParser.parse_args = parse_args
    try:
        sys.argv = [module, *args]
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            runpy.run_module(module, run_name="__main__", alter_sys=True)
    except Parsed as p:
        return p.args[0]
    except SystemExit as e:
        msg = f"{where}: {shlex.join(argv)}: exit {e.code}: {err.getvalue()}"
        raise AssertionError(msg) from None
    finally:
        argparse.ArgumentParser.parse_args = original
        sys.argv = old_argv
    raise AssertionError(f"{where}: {shlex.join(argv)} never parsed its arguments")


def check_python_source(code: str, where: str, *, imports: bool) -> None:
    """Compile ``code``; with ``imports``, run its import statements (the names it uses exist)."""
    tree = ast.parse(code, where)
    compile(tree, where, "exec")
    if imports:
        head = [n for n in tree.body if isinstance(n, ast.Import | ast.ImportFrom)]
        exec(compile(ast.Module(head, []), where, "exec"), {})


def parse_bash(code: str, where: str) -> int:
    """Parse every command of a bash block (the module docstring's rule); how many."""
    n = 0
    for argv, body in commands(code):
        n += 1
        if argv[:2] == ["python", "-m"] and argv[2].startswith("slotv_jax"):
            run_parser(argv, where)
        elif argv[:2] == ["python", "-"]:
            assert body is not None, where
            check_python_source(body, where, imports=True)
        elif argv[0] == "cat":
            assert body is not None or len(argv) > 1, where
        elif argv[:2] == ["python", "-m"] and argv[2] == "pytest":
            assert shlex.join(argv) in "\n".join(ci_lines()), f"{where}: .ci/run runs other tests"
        elif argv[0] == "pip":
            assert any(shlex.split(x, comments=True) == argv for x in ci_lines()), (
                f"{where}: .ci/run installs otherwise than {shlex.join(argv)}"
            )
        elif argv[0] == "sphinx-build":
            from sphinx.cmd.build import get_parser  # the docs' own dependency

            get_parser().parse_args(argv[1:])
        elif argv[0] in SHELL_WORDS or argv == ["server=$!"]:
            pass
        else:
            raise AssertionError(f"{where}: a command this test cannot check: {shlex.join(argv)}")
    return n


def parse_cases():
    for page in PAGES:
        for line, lang, mode, code in blocks(page):
            if lang == "bash" and (mode in ("default", "parse-only", "run") or "marked:" in mode):
                yield pytest.param(code, f"{page_id(page)}:{line}", id=f"{page_id(page)}:{line}")


@pytest.mark.parametrize("code, where", list(parse_cases()))
def test_bash_block_commands_parse(code, where):
    """Every command of a bash block passes its own parser (nothing runs past it)."""
    assert parse_bash(code, where) >= 1


def test_the_set_up_is_what_ci_runs():
    """The system packages of the README and getting started are those .ci/run installs,
    and both pages give its install and test commands."""
    ci = "\n".join(ci_lines())
    want = set()
    for m in re.finditer(r"apt-get install -y -qq ([^;}\n]+)", ci):
        want |= set(m.group(1).split())
    pages_with = 0
    for page in PAGES:
        for line, _, mode, code in blocks(page):
            if mode == "system":
                (argv, _), *rest = commands(code)
                assert not rest and argv[:3] == ["sudo", "apt-get", "install"], code
                assert set(argv[3:]) == want, (f"{page_id(page)}:{line}", want)
                pages_with += 1
    assert pages_with >= 1
    text = (ROOT / "README.md").read_text()
    install = next(line for line in ci_lines() if line.startswith("pip install"))
    assert f"{install}\npython -m pytest -q\n" in text, install


def test_the_bibtex_agrees_with_citation_cff():
    cff = yaml.safe_load((ROOT / "CITATION.cff").read_text())
    assert cff["cff-version"] == "1.2.0" and cff["license"] == "Apache-2.0"
    paper = cff["preferred-citation"]
    (bib,) = [c for p in PAGES for _, lang, _, c in blocks(p) if lang == "bibtex"]
    flat = re.sub(r"\s+", " ", bib).replace('{\\"o}', "ö")
    assert flat.count("{") == flat.count("}") and flat.startswith("@inproceedings{")
    title = re.search(r"title = \{(.*?)\},", flat).group(1).replace("{", "").replace("}", "")
    assert title == paper["title"]
    assert f"year = {{{paper['year']}}}" in flat
    assert f"eprint = {{{paper['url'].rsplit('/', 1)[1]}}}" in flat
    for a in paper["authors"]:
        assert a["given-names"] in flat and a["family-names"] in flat


def test_external_blocks_compile():
    n = 0
    for page in PAGES:
        for line, lang, mode, code in blocks(page):
            if mode != "external":
                continue
            where = f"{page_id(page)}:{line}"
            if lang == "python":
                check_python_source(code, where, imports=False)
            else:
                r = subprocess.run(["bash", "-n", "-c", code], capture_output=True, text=True)
                assert r.returncode == 0, (where, r.stderr)
            n += 1
    assert n >= 2


def test_parse_only_python_blocks_compile_and_import():
    """A parse-only python block compiles, and every name it imports exists."""
    n = 0
    for page in PAGES:
        for line, lang, mode, code in blocks(page):
            if lang == "python" and mode == "parse-only":
                check_python_source(code, f"{page_id(page)}:{line}", imports=True)
                n += 1
    assert n >= 1


def test_json_blocks_load():
    for page in PAGES:
        for _, lang, _, code in blocks(page):
            if lang == "json":
                json.loads(code)


# ----------------------------------------------------------------------- running


@pytest.fixture(scope="module")
def docs_data(tmp_path_factory, tiny_data, tiny_cfg):
    """A data/ folder holding the suite's tiny splits where --data quick finds them."""
    root = tmp_path_factory.mktemp("docs_data")
    home = data.dataset_dir(root / data.DEFAULT_CACHE, data.quick())
    home.mkdir(parents=True)
    for split in tiny_data.values():
        data.save_split(home, split, tiny_cfg)
    return root / data.DEFAULT_CACHE


def run_cases():
    for page in PAGES:
        todo = [
            b for b in blocks(page) if b[2] == "run" or (b[1] == "python" and b[2] == "default")
        ]
        if todo:
            yield pytest.param(page, id=page_id(page))


@pytest.mark.slow
@pytest.mark.parametrize("page", list(run_cases()))
def test_page_runs(page, docs_data, tmp_path, monkeypatch):
    """A page's python blocks (one namespace, in order) and its run blocks, in one folder."""
    (tmp_path / data.DEFAULT_CACHE).symlink_to(docs_data)
    (tmp_path / "experiments").symlink_to(ROOT / "experiments")
    monkeypatch.chdir(tmp_path)
    path = f"{Path(sys.executable).parent}:{os.environ.get('PATH', '/usr/bin:/bin')}"
    env = {**os.environ, "PYTHONPATH": str(ROOT), "PATH": path}
    namespace: dict = {"__name__": "__docs__"}
    for line, lang, mode, code in blocks(page):
        where = f"{page_id(page)}:{line}"
        if mode == "run":
            r = subprocess.run(["bash", "-e", "-c", code], cwd=tmp_path, env=env, text=True,
                               capture_output=True, timeout=600)  # fmt: skip
            assert r.returncode == 0, (where, r.stderr[-3000:])
        elif lang == "python" and mode == "default":
            exec(compile(code, where, "exec"), namespace)


def commands_of_the_package() -> set[str]:
    """Every ``python -m`` command: packages with a __main__.py, and modules with a
    top-level ``if __name__ == "__main__":`` (a package's cli.py is its package's)."""
    found = set()
    for path in (ROOT / "slotv_jax").rglob("*.py"):
        module = ".".join(path.relative_to(ROOT).with_suffix("").parts)
        if path.name == "__main__.py":
            found.add(module.removesuffix(".__main__"))
        elif re.search(r'^if __name__ == "__main__":', path.read_text(), re.M):
            if not (path.name == "cli.py" and (path.parent / "__main__.py").exists()):
                found.add(module)
    return found


def test_the_readme_lists_every_command_once():
    """The README's table of commands has one row per command, and only commands."""
    text = (ROOT / "README.md").read_text()
    rows = re.findall(r"^\| `python -m (slotv_jax[\w.]*)` \|", text, re.M)
    assert len(rows) == len(set(rows)), rows
    assert set(rows) == commands_of_the_package()
