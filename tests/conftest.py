"""Shared fixtures: one small, real, labelled dataset per test session."""

import os
import tempfile

# Rendering tests need an OpenGL backend, chosen before MuJoCo is first imported (below,
# through slotv_jax.data): EGL, a GPU's or Mesa's software one on a headless machine.
os.environ.setdefault("MUJOCO_GL", "egl")
# JAX's persistent compilation cache, shared by the two xdist workers and every command the
# tests start in a subprocess (set before jax is imported, so they all inherit it): a
# program compiled once in the run is loaded, not compiled again, by the next process.
# Keyed by the program, the compile options and the versions, so it changes no result.
os.environ.setdefault(
    "JAX_COMPILATION_CACHE_DIR",
    os.path.join(tempfile.gettempdir(), f"slotv_jax_tests_xla_cache_{os.getuid()}"),
)
# Every program is kept, not only those that compiled for a second or more (JAX's default):
# the suite's many small programs recur across its processes. On the 2-core VM this took
# the suite from 838 to 777 s, its tests' summed time from 1,628 to 1,512 s (one run each,
# 2026-11-29; experiments/BENCHMARKS.md, "The test suite").
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")

import pytest
from hypothesis import HealthCheck, settings

import slotv_jax  # noqa: F401  (applies the XLA CPU setting before jax starts)
from slotv_jax import data

# Property tests: derandomised (the same examples on every run and machine, so CI is
# reproducible) and bounded (a fixed number of examples; no deadline, since the first
# example of a test pays for JAX compilation). A test may ask for fewer examples.
settings.register_profile(
    "slotv_jax",
    derandomize=True,
    max_examples=30,
    deadline=None,
    print_blob=True,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
settings.load_profile("slotv_jax")

TINY = {"seed": 0, "n_train": 300, "n_eval": 100, "n_train_scenes": 20, "n_new_scenes": 4}


@pytest.fixture(scope="session")
def tiny_cfg() -> data.DataConfig:
    """The config of :func:`tiny_data` (chunk size 512, as in ``make_tiny_dataset``)."""
    return data.DataConfig(preset="tiny", chunk_size=512, **TINY)


@pytest.fixture(scope="session")
def tiny_data(tiny_cfg) -> dict[str, data.Split]:
    """All seven splits, generated and labelled (about 20 s on 2 cores, mostly compilation)."""
    return data.generate_dataset(tiny_cfg, None, progress=False)
