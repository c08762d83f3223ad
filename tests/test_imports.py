"""The package's import structure (STYLE principle 14: dependencies point down).

Every module of ``slotv_jax`` is parsed with ``ast`` (nothing is imported) to build the
graph of its module-level imports of other ``slotv_jax`` modules; the graph must be
acyclic. An import inside a function is allowed only for an optional heavy dependency
(:data:`OPTIONAL`) or for one of the named, justified exceptions below. Then a fresh
interpreter checks that the low modules load without the ones above them.
"""

from __future__ import annotations

import ast
import functools
import os
import subprocess
import sys
from pathlib import Path

import slotv_jax

PACKAGE_DIR = Path(slotv_jax.__file__).parent
# Optional heavy dependencies, imported where they are used: plotting, and SciPy (a test
# extra) for the planning benchmark's baseline.
OPTIONAL = ("matplotlib", "scipy")
# (importing module, imported module prefix): why it is imported inside a function.
EXCEPTIONS = {
    # PEP 562 load_observer: `import slotv_jax` stays cheap and `python -m slotv_jax.X`
    # does not find X already imported (see slotv_jax/__init__.py).
    ("slotv_jax", "slotv_jax.training.checkpoint"): "lazy package attribute",
    # Consulted only when JAX is already imported: _xla must not import JAX itself.
    ("slotv_jax.core.xla", "jax._src"): "probe of an already imported JAX",
    # Loaded on first use, not when a command starts (each about a second or more on the
    # 2-core CPU, paid by every `python -m slotv_jax.X`, --help included): MJX is only the
    # kinematics' reference, toppra (SciPy's interpolation, matplotlib) only times plans.
    ("slotv_jax.robot.kinematics", "mujoco"): "mujoco.mjx, the reference, on first use",
    ("slotv_jax.execution.timing", "slotv_jax.execution.topp"): "toppra, on first timing",
    ("slotv_jax.execution.path", "toppra"): "toppra's spline, on first path",
}


def _module_name(path: Path) -> str:
    rel = path.relative_to(PACKAGE_DIR.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


MODULES = {_module_name(p): p for p in sorted(PACKAGE_DIR.rglob("*.py"))}


def _targets(node: ast.Import | ast.ImportFrom, module: str) -> list[str]:
    """The modules an import statement loads (absolute names)."""
    if isinstance(node, ast.Import):
        return [a.name for a in node.names]
    base = node.module or ""
    if node.level:  # relative import
        pkg = module if MODULES[module].name == "__init__.py" else module.rpartition(".")[0]
        for _ in range(node.level - 1):
            pkg = pkg.rpartition(".")[0]
        base = f"{pkg}.{base}".rstrip(".")
    subs = [f"{base}.{a.name}" for a in node.names if f"{base}.{a.name}" in MODULES]
    # ``from pkg import sub``: the names come from the submodules (the package's
    # __init__ runs first for any import of it; that is no dependency on its names)
    return subs if len(subs) == len(node.names) else [base, *subs]


def _is_main_guard(node: ast.stmt) -> bool:
    """``if __name__ == "__main__":`` — code that runs only as a script."""
    t = getattr(node, "test", None)
    return (
        isinstance(node, ast.If)
        and isinstance(t, ast.Compare)
        and isinstance(t.left, ast.Name)
        and t.left.id == "__name__"
    )


def _module_level(stmts, module: str):
    """Imports executed when the module is imported (also inside module-level if/try)."""
    for node in stmts:
        if isinstance(node, ast.Import | ast.ImportFrom):
            yield node
        elif isinstance(node, ast.If | ast.Try | ast.With) and not _is_main_guard(node):
            for field in ("body", "orelse", "finalbody", "handlers"):
                for child in getattr(node, field, []):
                    yield from _module_level(
                        getattr(child, "body", [child]) if field == "handlers" else [child],
                        module,
                    )


def _function_imports(tree: ast.Module):
    """(function name, import node) for every import inside a function or lambda."""
    for fn in ast.walk(tree):
        if isinstance(fn, ast.FunctionDef | ast.AsyncFunctionDef):
            for node in ast.walk(fn):
                if isinstance(node, ast.Import | ast.ImportFrom):
                    yield fn.name, node


@functools.cache
def _tree(path: Path) -> ast.Module:
    return ast.parse(path.read_text(), str(path))


@functools.cache
def import_graph() -> dict[str, set[str]]:
    """module -> the slotv_jax modules it imports at module level."""
    graph = {}
    for name, path in MODULES.items():
        tree = _tree(path)
        deps = set()
        for node in _module_level(tree.body, name):
            deps |= {t for t in _targets(node, name) if t in MODULES and t != name}
        graph[name] = deps
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle of ``graph`` as a list of modules (first = last), or None."""
    state: dict[str, int] = {}  # 1: on the stack, 2: done
    stack: list[str] = []

    def visit(u):
        state[u] = 1
        stack.append(u)
        for v in sorted(graph[u]):
            if state.get(v) == 1:
                return [*stack[stack.index(v) :], v]
            if v not in state and (c := visit(v)):
                return c
        stack.pop()
        state[u] = 2
        return None

    for u in sorted(graph):
        if u not in state and (c := visit(u)):
            return c
    return None


def test_find_cycle_finds_one():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": set()}) is None


def test_module_level_imports_are_acyclic():
    graph = import_graph()
    assert {
        "slotv_jax.training.types",
        "slotv_jax.training.evaluate",
        "slotv_jax.training.trainer",
    } <= set(graph)
    cycle = find_cycle(graph)
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def test_dependencies_point_down():
    """The layers named in the issue: evaluation below training, training below checkpoints
    and studies, the shared types below all of them."""
    graph = import_graph()

    def reaches(a, b):
        seen, todo = set(), [a]
        while todo:
            u = todo.pop()
            if u == b:
                return True
            if u not in seen:
                seen.add(u)
                todo.extend(graph[u])
        return False

    assert not reaches("slotv_jax.training.evaluate", "slotv_jax.training.trainer")
    assert not reaches("slotv_jax.training.trainer", "slotv_jax.training.checkpoint")
    assert not reaches("slotv_jax.training.trainer", "slotv_jax.answers")
    assert not reaches("slotv_jax.training.types", "slotv_jax.observers.models")
    for user in (
        "training.evaluate",
        "training.trainer",
        "training.checkpoint",
        "training.parallel",
        "answers",
    ):
        assert reaches(f"slotv_jax.{user}", "slotv_jax.training.types"), user


# The package's folders are its layers, bottom up (ARCHITECTURE.md draws them): a module
# imports only modules of its own folder or of a lower layer. Folders of one layer do not
# import each other. The public names of :ref:`concepts-public-names` and the commands stand above
# the library.
LAYERS = (
    ("core",),
    ("robot",),
    ("world",),
    ("observers",),
    ("data", "planning", "training", "rendering"),
    ("answers", "runs", "execution"),
    ("asking", "webstudy"),
    ("study",),
    ("", "labelers", "train", "render", "scene", "kinematics"),
    ("experiments", "benchmarks"),
)


def _folder(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


def test_folders_are_layers():
    rank = {f: i for i, layer in enumerate(LAYERS) for f in layer}
    graph = import_graph()
    unplaced = sorted({_folder(m) for m in graph} - set(rank))
    assert not unplaced, f"folders missing from LAYERS: {unplaced}"
    bad = [
        f"{a} -> {b}"
        for a, deps in graph.items()
        for b in deps
        if _folder(a) != _folder(b) and rank[_folder(b)] >= rank[_folder(a)]
    ]
    assert not bad, "imports that do not point down a layer:\n" + "\n".join(sorted(bad))


def test_no_imports_inside_functions():
    bad = []
    for name, path in MODULES.items():
        tree = _tree(path)
        for fn, node in _function_imports(tree):
            for target in _targets(node, name)[:1]:
                top = target.split(".")[0]
                if top in OPTIONAL:
                    continue
                if any(
                    name == m and (target == p or target.startswith(p + ".")) for m, p in EXCEPTIONS
                ):
                    continue
                bad.append(f"{path.relative_to(PACKAGE_DIR.parent)}:{node.lineno} in {fn}(): "
                           f"{ast.unparse(node)}")  # fmt: skip
    assert not bad, "imports inside functions (move them to module level):\n" + "\n".join(bad)


def test_train_script_runs_without_double_import_warning():
    r = subprocess.run(
        [sys.executable, "-W", "error::RuntimeWarning", "-m", "slotv_jax.train", "--help"],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr[-2000:]
    assert "--study" in r.stdout


COMMANDS_LOAD_NEITHER = """
import sys
from slotv_jax.data import cli as _data
from slotv_jax.execution import cli as _execution
from slotv_jax.labelers import cli as _labelers
from slotv_jax.render import cli as _render
from slotv_jax.study import cli as _study
from slotv_jax.train import cli as _train
from slotv_jax.world import scene

scene.camera("observer"), scene.camera("observer_side")  # posed by MuJoCo C
heavy = sorted(m for m in ("toppra", "mujoco.mjx", "scipy.interpolate") if m in sys.modules)
assert not heavy, heavy
print("OK")
"""


def test_commands_start_without_toppra_or_mjx():
    """A command's start (``--help`` too) and the scene's cameras load neither toppra (with
    SciPy's interpolation and matplotlib, about 1.6 s) nor MJX (about a second): they load
    when a plan is first timed, or the MJX reference is asked for."""
    r = subprocess.run([sys.executable, "-c", COMMANDS_LOAD_NEITHER], capture_output=True,
                       text=True, check=False)  # fmt: skip
    assert r.returncode == 0 and r.stdout.strip() == "OK", r.stderr[-2000:]


IMPORT_EVERYTHING = """
import importlib, os, pkgutil, subprocess, sys

started = []


class Watch(subprocess.Popen):
    def __init__(self, *args, **kwargs):
        f = sys._getframe(1)
        while f and f.f_code.co_filename.endswith("subprocess.py"):
            f = f.f_back
        if f and os.sep + "slotv_jax" + os.sep in f.f_code.co_filename:
            started.append(f"{f.f_code.co_filename}:{f.f_lineno}")
        super().__init__(*args, **kwargs)


subprocess.Popen = Watch
import slotv_jax

# the low modules load alone: `import slotv_jax` loads no JAX, evaluation loads neither
# training nor checkpoints, and load_observer is the checkpoint's
assert "jax" not in sys.modules, "import slotv_jax loads JAX"
import slotv_jax.training.evaluate

above = ("slotv_jax.training.trainer", "slotv_jax.training.checkpoint", "slotv_jax.answers",
         "slotv_jax.study", "slotv_jax.data")
assert not [m for m in above if m in sys.modules], [m for m in above if m in sys.modules]
from slotv_jax import load_observer

assert load_observer is slotv_jax.training.checkpoint.load_observer

for m in pkgutil.walk_packages(slotv_jax.__path__, "slotv_jax."):
    if not m.name.endswith("__main__"):
        importlib.import_module(m.name)
assert not started, f"processes started by slotv_jax on import: {started}"
"""


def test_importing_prints_nothing_and_starts_no_process(tmp_path, monkeypatch):
    """In a fresh interpreter, the low modules load without those above them, and importing
    every module of the package writes nothing to stdout or stderr and starts no process of
    its own. The XLA flag probe is the one exception, and it runs once per
    installation: with its answers cached (here: written first), it starts none either."""
    from slotv_jax.core import xla

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    monkeypatch.setattr(xla, "probe_flag", lambda flag: True)
    for flag in xla.FLAGS:
        assert xla.flag_supported(flag)
    env = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS", xla.OPT_OUT_VAR)}
    r = subprocess.run(
        [sys.executable, "-c", IMPORT_EVERYTHING], env=env, capture_output=True, text=True,
        check=False, timeout=300,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr[-3000:]
    assert r.stdout == "" and r.stderr == "", (r.stdout + r.stderr)[-3000:]


def test_third_party_imports_are_declared_dependencies():
    """Every module-level import of another distribution is one of the package's own
    dependencies (pyproject's ``[project] dependencies``), so that a plain ``pip install``
    runs every command; test extras may appear only inside functions (:data:`OPTIONAL`).
    (``study`` once imported httpx, then a test extra, and failed without it.)"""
    import importlib.metadata
    import re
    import tomllib

    project = tomllib.loads((PACKAGE_DIR.parent / "pyproject.toml").read_text())["project"]
    norm = lambda d: re.split(r"[<>=!~\[; ]", d, maxsplit=1)[0].lower().replace("_", "-")  # noqa: E731
    declared = {norm(d) for d in project["dependencies"]}
    dists = importlib.metadata.packages_distributions()  # top-level module -> distributions
    missing: dict[str, set[str]] = {}
    for name, path in MODULES.items():
        for node in _module_level(_tree(path).body, name):
            if isinstance(node, ast.ImportFrom) and node.level:
                continue  # relative: the package itself
            mods = [a.name for a in node.names] if isinstance(node, ast.Import) else [node.module]
            for top in {m.split(".")[0] for m in mods}:
                if top in ("slotv_jax", "__future__") or top in sys.stdlib_module_names:
                    continue
                if not {norm(d) for d in dists.get(top, [])} & declared:
                    missing.setdefault(top, set()).add(name)
    assert not missing, f"imported at module level but not a dependency: {missing}"


PUBLIC_NAMES = """
import sys
import slotv_jax
print(sorted(dir(slotv_jax)))
print("slotv_jax.training.checkpoint" in sys.modules)
"""


def test_dir_lists_exactly_the_public_names_and_keeps_the_import_lazy():
    """A fresh ``import slotv_jax``: ``dir`` (what completion and ``help()`` read) is the
    package's ``__all__``, ``load_observer`` in it and no helper or layer module
    (``XlaConfig``, ``choose_mujoco_gl``, ``core``), and listing it imports no
    checkpoint code (0.8-1.4 s against 17-18 s with it, measured on the loaded 2-core CPU);
    every listed name is an attribute, the lazy one the checkpoint's own function."""
    import slotv_jax
    from slotv_jax.training import checkpoint

    r = subprocess.run([sys.executable, "-c", PUBLIC_NAMES], capture_output=True, text=True,
                       check=False, timeout=300)  # fmt: skip
    assert r.returncode == 0, r.stderr[-3000:]
    listed, loaded = r.stdout.splitlines()
    assert listed == str(["XLA_CONFIG", "__version__", "load_observer"])
    assert loaded == "False"
    assert sorted(dir(slotv_jax)) == sorted(slotv_jax.__all__)
    assert slotv_jax.load_observer is checkpoint.load_observer
    assert all(hasattr(slotv_jax, n) for n in slotv_jax.__all__)
