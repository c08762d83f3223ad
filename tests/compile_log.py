"""What XLA compiles inside a block: the tests that count compilations share this."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

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
