"""What a long stage shows while it reports nothing of its own: a compilation.

Long loops show a tqdm bar. A compilation (a minute or more on a busy CPU for the
planner or the IK) reports no progress; the stage says so before it starts, as a bar's
note or as one line on stderr (:func:`status`), and only when the call will compile
(:func:`has_compiled`).

>>> import jax  # doctest: +SKIP
>>> f = jax.jit(lambda x: x + 1)  # doctest: +SKIP
>>> has_compiled(f)  # doctest: +SKIP
False
"""

from __future__ import annotations

import sys
from collections.abc import Callable

from tqdm.auto import tqdm


def has_compiled(fn: Callable) -> bool:
    """Whether the jitted ``fn`` holds a compiled program (for any arguments), so that a
    note says "compiling" only before a call that does; False where JAX does not tell. It
    reads jit's executable cache, which drops entries late in a long process: then a note may
    say "compiling" for a program XLA still holds. Only a note rests on it; a stage whose
    note must be right keeps its compiled programs itself, as
    :func:`~slotv_jax.training.trainer.train_trials` does."""
    size = getattr(fn, "_cache_size", None)
    return bool(size is not None and size() > 0)


def status(text: str) -> None:
    """One line on stderr that says what a silent stage is doing (printed above any tqdm
    bars, which stay intact)."""
    tqdm.write(text, file=sys.stderr)
    sys.stderr.flush()
