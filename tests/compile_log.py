"""What XLA compiles inside a block, and how often JAX traces a function: the tests that
count compilations share this."""

from __future__ import annotations

import contextlib
import functools
from collections.abc import Callable, Iterator

import jax


@contextlib.contextmanager
def backend_compiles() -> Iterator[list[str]]:
    """A list that fills with the names of the functions XLA compiles inside the ``with``
    block (``jax.monitoring``'s ``backend_compile_duration`` events); the listener is
    removed when the block ends, also on an error."""
    compiled: list[str] = []

    def listen(event: str, duration: float, **kw) -> None:
        if event.endswith("backend_compile_duration"):
            compiled.append(kw.get("fun_name"))

    jax.monitoring.register_event_duration_secs_listener(listen)
    try:
        yield compiled
    finally:
        jax.monitoring.unregister_event_duration_listener(listen)


def counting_traces(fn: Callable) -> tuple[Callable, list[int]]:
    """``fn`` and a list that grows by one each time JAX traces it (its Python body runs
    only when a jitted caller compiles a new program): ``len(list) == 1`` after several calls
    says that they shared one program. Unlike a jitted function's ``_cache_size()``, this does
    not read jit's executable cache, which the whole process shares and which drops entries
    late in a long process."""
    traces: list[int] = []

    @functools.wraps(fn)
    def traced(*args, **kwargs):
        traces.append(1)
        return fn(*args, **kwargs)

    return traced, traces
