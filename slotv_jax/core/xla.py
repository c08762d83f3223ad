"""The XLA CPU settings that slotv_jax applies when it is imported.

Two settings of XLA's CPU backend, each measured against XLA's default:

- ``--xla_cpu_use_fusion_emitters=false``. XLA compiles elementwise fusions with its
  newer "fusion emitters" by default. MJX kinematics is a long chain of tiny fusions
  (quaternion products, 3-vectors, one body at a time), and with the fusion emitters
  on, each of them costs far more than the arithmetic it does: measured on a 2-core
  CPU with jax 0.10.2 and mujoco-mjx 3.17, one jitted ``mjx.kinematics`` call took
  ~6 ms with the default and ~50 µs with the flag (see
  ``python -m slotv_jax.benchmarks.kinematics``). The arm's kinematics is now the MJCF's
  chain (:mod:`slotv_jax.robot.kinematics`), whose single call is faster without the flag,
  but the planner still compiled faster with it and the tiny dataset generated about twice
  as fast (2026-12-03, experiments/BENCHMARKS.md, Planning), so it stays.
- ``--xla_cpu_prefer_vector_width=512``. XLA asks LLVM for 256-bit vectors by default,
  so on a CPU with AVX-512 half of each vector register goes unused. The labelers'
  loops (a distance, an exponential or a square root per point and goal) are bound by
  exactly that arithmetic: ``jax.jit(jax.vmap(labelers.dragan))`` on 160,000
  trajectories took 153 ms with the default and 96 ms with the flag on the project's
  2-core AVX-512 VM (``python -m slotv_jax.benchmarks.labeling``; 1.3-1.6x for all four
  labelers, experiments/BENCHMARKS.md), and the quick Table 1 job was not slower. On a
  CPU without AVX-512 LLVM cannot use wider vectors than it has, and the flag changes
  nothing. It changes float rounding (the order of vectorised sums), not results
  beyond it.

Matrix-heavy code (the MLP training) calls its own kernels and is unaffected by either.

Rules, in order:

1. ``SLOTV_JAX_XLA_FLAGS=0`` in the environment: nothing is changed.
2. A setting whose flag the user's ``XLA_FLAGS`` already mention keeps the user's value.
3. JAX's backends are already initialised (XLA reads ``XLA_FLAGS`` once, when
   the first backend starts): nothing can be changed; a warning says so and how
   to set the flags by hand.
4. A flag the installed XLA does not know is left out. XLA aborts the process on an
   unknown flag (jaxlib 0.11.2 with its CUDA plugin does, for the first one), so
   support is probed once per flag and installation in a subprocess
   (``import jax; jax.devices()`` with the flag set) and the answer is cached in
   ``~/.cache/slotv_jax/xla_flags.json`` (``$XDG_CACHE_HOME`` is honoured), keyed by
   the Python executable, the versions of the installed JAX packages and the flag.
5. The remaining flags are appended to ``XLA_FLAGS``; other flags are kept.

What happened is recorded in :data:`XLA_CONFIG`, logged on the ``slotv_jax``
logger, printed by every command-line entry point, and stored with every
experiment's results.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import os
import subprocess
import sys
import warnings
from collections.abc import Callable
from importlib import metadata
from pathlib import Path

from slotv_jax.core.fileio import write_text

# flag name -> (value, why), in the order they are appended
SETTINGS: dict[str, tuple[str, str]] = {
    "xla_cpu_use_fusion_emitters": ("false", "faster MJX kinematics on the CPU"),
    "xla_cpu_prefer_vector_width": ("512", "full-width vectors for the labelers on AVX-512 CPUs"),
}
FLAGS: tuple[str, ...] = tuple(f"--{name}={value}" for name, (value, _) in SETTINGS.items())
OPT_OUT_VAR = "SLOTV_JAX_XLA_FLAGS"

_log = logging.getLogger("slotv_jax")


@dataclasses.dataclass(frozen=True)
class XlaConfig:
    """What slotv_jax did to ``XLA_FLAGS`` at import time."""

    applied: tuple[str, ...]  # flags slotv_jax appended (empty if none)
    xla_flags: str  # XLA_FLAGS as it stood after the decision
    reason: str  # one line, for humans

    def summary(self) -> str:
        """One line saying what was applied and why."""
        if self.applied:
            return (
                f"slotv_jax: appended {' '.join(self.applied)} to XLA_FLAGS ({self.reason}; "
                f"set {OPT_OUT_VAR}=0 to opt out)"
            )
        return f"slotv_jax: XLA_FLAGS left unchanged ({self.reason})"


def _backends_initialised() -> bool:
    if "jax" not in sys.modules:
        return False
    from jax._src import xla_bridge

    return bool(xla_bridge.backends_are_initialized())


def _jax_packages() -> str:
    """Versions of the installed JAX packages (jax, jaxlib, PJRT plugins), one string."""

    found = set()
    for dist in metadata.distributions():
        name = (dist.metadata["Name"] or "").lower().replace("_", "-")
        if name.startswith(("jax", "libtpu")):
            found.add(f"{name}=={dist.version}")
    return ";".join(sorted(found))


def _cache_path() -> Path:
    root = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(root) / "slotv_jax" / "xla_flags.json"


def probe_flag(flag: str, timeout: float = 180.0) -> bool:
    """Whether a fresh interpreter starts JAX's backends with ``flag`` in ``XLA_FLAGS``."""
    env = {**os.environ, "XLA_FLAGS": flag, "XLA_PYTHON_CLIENT_PREALLOCATE": "false"}
    env[OPT_OUT_VAR] = "0"
    try:
        r = subprocess.run(
            [sys.executable, "-c", "import jax; jax.devices()"],
            env=env,
            capture_output=True,
            timeout=timeout,
            check=False,
        )
    except (OSError, subprocess.TimeoutExpired):
        return False
    return r.returncode == 0


def flag_supported(flag: str) -> bool:
    """:func:`probe_flag`, cached on disk per Python executable and JAX package versions."""
    key = hashlib.sha256(f"{sys.executable}|{_jax_packages()}|{flag}".encode()).hexdigest()
    path = _cache_path()
    try:
        cache = json.loads(path.read_text())
        if isinstance(cache, dict) and isinstance(cache.get(key), bool):
            return cache[key]
    except (OSError, ValueError):
        cache = {}
    ok = probe_flag(flag)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_text(path, json.dumps({**(cache if isinstance(cache, dict) else {}), key: ok}))
    except OSError:
        pass  # an unwritable cache only means probing again next time
    return ok


def configure(
    environ: dict[str, str] | None = None, *, supported: Callable[[str], bool] | None = None
) -> XlaConfig:
    """Apply the CPU settings to ``environ`` (default ``os.environ``) by the rules above.

    ``supported(flag)`` answers rule 4; it defaults to :func:`flag_supported` for the
    process environment and to "yes" for an explicit ``environ`` dict.
    """
    env = os.environ if environ is None else environ
    if supported is None:
        supported = flag_supported if environ is None else (lambda flag: True)
    current = env.get("XLA_FLAGS", "")
    if env.get(OPT_OUT_VAR, "").strip().lower() in {"0", "false", "no", "off"}:
        return XlaConfig((), current, f"disabled by {OPT_OUT_VAR}=0")
    wanted = [(f, n) for f, n in zip(FLAGS, SETTINGS, strict=True) if n not in current]
    if not wanted:
        return XlaConfig((), current, f"the user's XLA_FLAGS already set {', '.join(SETTINGS)}")
    if environ is None and _backends_initialised():
        flags = " ".join(f for f, _ in wanted)
        warnings.warn(
            f"slotv_jax was imported after JAX started its backends, so it could not set "
            f"{flags}; MJX kinematics and labelling on the CPU will be slower. Import "
            f"slotv_jax before using JAX, or start Python with XLA_FLAGS='{flags}'.",
            RuntimeWarning,
            stacklevel=3,
        )
        return XlaConfig((), current, "JAX backends were already initialised")
    known = [(f, n) for f, n in wanted if supported(f)]
    unknown = [n for f, n in wanted if (f, n) not in known]
    notes = [f"this XLA build does not know {n}" for n in unknown]
    notes += [f"the user's XLA_FLAGS already set {n}" for n in SETTINGS if n in current]
    if not known:
        return XlaConfig((), current, "; ".join(notes))
    new = " ".join([current.strip(), *(f for f, _ in known)]).strip()
    env["XLA_FLAGS"] = new
    reason = "; ".join([*(SETTINGS[n][1] for _, n in known), *notes])
    return XlaConfig(tuple(f for f, _ in known), new, reason)


XLA_CONFIG: XlaConfig = configure()
_log.info(XLA_CONFIG.summary())
