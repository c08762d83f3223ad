"""The XLA CPU setting that slotv_jax applies when it is imported.

XLA's CPU backend compiles elementwise fusions with its newer "fusion emitters"
by default. MJX kinematics is a long chain of tiny fusions (quaternion products,
3-vectors, one body at a time), and with the fusion emitters on, each of them
costs far more than the arithmetic it does: measured on a 2-core CPU with jax
0.10.2 and mujoco-mjx 3.17, one jitted ``mjx.kinematics`` call took ~6 ms with
the default and ~50 µs with ``--xla_cpu_use_fusion_emitters=false`` (see
``python -m slotv_jax.benchmarks.kinematics``). Matrix-heavy code (the MLP
training) is unaffected, so the package turns the emitters off.

Rules, in order:

1. ``SLOTV_JAX_XLA_FLAGS=0`` in the environment: nothing is changed.
2. The user's ``XLA_FLAGS`` already mention ``xla_cpu_use_fusion_emitters``:
   their value is kept.
3. JAX's backends are already initialised (XLA reads ``XLA_FLAGS`` once, when
   the first backend starts): nothing can be changed; a warning says so and how
   to set the flag by hand.
4. Otherwise the flag is appended to ``XLA_FLAGS``; other flags are kept.

What happened is recorded in :data:`XLA_CONFIG`, logged on the ``slotv_jax``
logger, printed by every command-line entry point, and stored with every
experiment's results.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import sys
import warnings

FLAG_NAME = "xla_cpu_use_fusion_emitters"
FLAG = f"--{FLAG_NAME}=false"
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


def configure(environ: dict[str, str] | None = None) -> XlaConfig:
    """Apply the CPU setting to ``environ`` (default ``os.environ``) by the rules above."""
    env = os.environ if environ is None else environ
    current = env.get("XLA_FLAGS", "")
    if env.get(OPT_OUT_VAR, "").strip().lower() in {"0", "false", "no", "off"}:
        return XlaConfig((), current, f"disabled by {OPT_OUT_VAR}=0")
    if FLAG_NAME in current:
        return XlaConfig((), current, f"the user's XLA_FLAGS already set {FLAG_NAME}")
    if environ is None and _backends_initialised():
        warnings.warn(
            "slotv_jax was imported after JAX started its backends, so it could not set "
            f"{FLAG}; MJX kinematics on the CPU will be much slower. Import slotv_jax "
            f"before using JAX, or start Python with XLA_FLAGS={FLAG}.",
            RuntimeWarning,
            stacklevel=3,
        )
        return XlaConfig((), current, "JAX backends were already initialised")
    new = f"{current} {FLAG}".strip()
    env["XLA_FLAGS"] = new
    return XlaConfig((FLAG,), new, "faster MJX kinematics on the CPU")


XLA_CONFIG: XlaConfig = configure()
_log.info(XLA_CONFIG.summary())
