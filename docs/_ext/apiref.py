"""The API reference's lists of re-exported names and the modules it must cover.

``public-names MODULE``: a list of the names in ``MODULE.__all__``, each linked to the one
place it is documented (the module that defines it), so that a package's public face (or a
compatibility alias) names its ideas without describing them twice.
:func:`public_modules` is what the API pages must cover (``tests/test_docs.py``).
"""

from __future__ import annotations

import importlib
import inspect
import re
import sys
from pathlib import Path

from docutils import nodes
from sphinx import addnodes
from sphinx.util.docutils import SphinxDirective

PACKAGE = Path(__file__).resolve().parents[2] / "slotv_jax"


def public_modules() -> list[str]:
    """Every module and package of ``slotv_jax`` whose dotted name has no part starting
    with ``_`` (``__init__`` stands for its package; ``__main__`` is a command's runner)."""
    names = []
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        if any(p.startswith("_") for p in parts):
            continue
        names.append(".".join(parts))
    return names


def home(module: str, name: str) -> tuple[str, str]:
    """``(role, dotted name)`` of where ``module.name`` is documented: the package module
    whose source defines it (``def NAME``, ``class NAME``, ``NAME = ...``)."""
    obj = getattr(importlib.import_module(module), name)
    if inspect.ismodule(obj):
        return "mod", obj.__name__
    defines = re.compile(rf"^(?:def |class |async def )?{re.escape(name)}\b\s*[:=(]", re.M)
    for other in public_modules():
        mod = sys.modules.get(other)
        if mod is None or other == module or getattr(mod, name, None) is not obj:
            continue
        if defines.search(Path(mod.__file__).read_text()):
            return "obj", f"{other}.{name}"
    return "obj", f"{module}.{name}"


class PublicNames(SphinxDirective):
    """``public-names MODULE``: its ``__all__`` as a list of links to their definitions."""

    required_arguments = 1

    def run(self) -> list[nodes.Node]:
        module = self.arguments[0]
        names = getattr(importlib.import_module(module), "__all__", None)
        if names is None:
            raise self.error(f"public-names: {module} has no __all__")
        items = nodes.bullet_list()
        for name in names:
            role, target = home(module, name)
            ref = addnodes.pending_xref(
                "", refdomain="py", reftype=role, reftarget=target, refexplicit=True
            )
            ref += nodes.literal(name, name)
            para = nodes.paragraph()
            para += ref
            if target != f"{module}.{name}":
                para += nodes.Text(" — ")
                para += nodes.literal(target, target)
            items += nodes.list_item("", para)
        return [items]


def setup(app):
    app.add_directive("public-names", PublicNames)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
