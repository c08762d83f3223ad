"""Where, when and how a recorded run ran: what a results document keeps beside its numbers
so that its report says it, and can be rendered again from the document alone.

>>> command_line("python -m slotv_jax.experiments.active", ["--preset", "paper", "--no-progress"])
'python -m slotv_jax.experiments.active --preset paper'
"""

from __future__ import annotations

import os
import platform
import re
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path

import jax

VERSIONS = ("python", "jax", "flax", "optax", "numpy")  # the versions a report names


def machine() -> str:
    """The machine in words: architecture, CPU count and the first device, e.g.
    ``x86_64, 16 CPUs, gpu: NVIDIA H100 80GB HBM3``."""
    dev = jax.devices()[0]
    return f"{platform.machine()}, {os.cpu_count()} CPUs, {dev.platform}: {dev.device_kind}"


def load_start() -> dict:
    """The CPU count and the 1-minute load average now (a run's start on a shared machine)."""
    return {"cpus": os.cpu_count(), "start": os.getloadavg()[0]}


def load_end(start: Mapping) -> dict:
    """``start`` (:func:`load_start`) with the 1-minute load average now as its end."""
    return {**start, "end": os.getloadavg()[0]}


def utc_now() -> str:
    """The date and minute in UTC, as reports print it (``2026-11-25 06:56 UTC``)."""
    return time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())


def versions(env: Mapping, keys: Sequence[str] = VERSIONS) -> str:
    """``python 3.11.7, jax 0.10.2, ...``: the versions of ``keys`` that the environment
    (:func:`slotv_jax.core.environment.environment`) holds."""
    return ", ".join(f"{k} {env[k]}" for k in keys if k in env)


#: Flags that change how a run looks, not what it computes: left out of the recorded command,
#: so that a rerun with or without them draws the same report.
DISPLAY_FLAGS = ("--no-progress",)


def command_line(prog: str, argv: Sequence[str] | None) -> str:
    """The command that made the results: ``prog`` and its arguments (``argv``, or the
    process's own when None), less the :data:`DISPLAY_FLAGS`."""
    args = sys.argv[1:] if argv is None else argv
    return " ".join([prog, *(a for a in args if a not in DISPLAY_FLAGS)])


def with_out(commands: str, out: str | Path, default: str | Path) -> str:
    """``commands`` (lines of a report's command block) with ``--out OUT`` added to each
    ``python -m`` line that names no ``--out``, unless ``out`` is the command's ``default``
    (before a trailing ``  # comment``), so that each line writes where its report is.

    >>> with_out("python -m m --preset paper  # resumes", "experiments", "runs")
    'python -m m --preset paper --out experiments  # resumes'
    """
    if Path(out) == Path(default):
        return commands
    lines = []
    for line in commands.split("\n"):
        code, sep, comment = line.partition("  # ")
        if code.startswith("python -m ") and "--out" not in code.split():
            code = f"{code.rstrip()} --out {out}"
        lines.append(code + sep + comment)
    return "\n".join(lines)


def recorded_command(report: str | Path) -> str | None:
    """The command block of a rendered report (the first fenced ``bash`` block: the
    commands that made its results), or None if ``report`` does not exist or has none."""
    path = Path(report)
    if not path.is_file():
        return None
    m = re.search(r"```bash\n(.*?)\n```", path.read_text(encoding="utf-8"), re.S)
    return m.group(1) if m else None
