"""Batch sizes that do not recompile: a jitted function compiles once per input shape, so a
caller whose batch size changes from call to call (the rows of a growing study, the
stimuli of each round) pads its batch to a few sizes instead of compiling for every one."""

from __future__ import annotations

import numpy as np


def bucket(n: int, least: int = 8) -> int:
    """The smallest power of two >= max(n, least): at most log2(N) shapes for N rows."""
    if n < 0:
        raise ValueError(f"n: expected a count >= 0, got {n}")
    return 1 << (max(n, least) - 1).bit_length()


def pad_rows(a: np.ndarray, size: int) -> np.ndarray:
    """``a`` (n, ...) with its first row repeated up to ``size`` rows (n >= 1); callers of a
    row-wise (vmapped) function keep the first n rows of the result, unchanged by the
    padding."""
    a = np.asarray(a)
    if a.shape[0] < 1 or size < a.shape[0]:
        raise ValueError(f"size: expected >= {a.shape[0]} rows (and >= 1), got {size}")
    return np.concatenate([a, np.repeat(a[:1], size - a.shape[0], axis=0)])
