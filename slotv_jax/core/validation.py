"""Checks for user input at the public boundary.

Every check raises :class:`ValueError` naming the argument and what was
expected. Shape checks always run; value checks (NaN, ranges) run only on
concrete arrays, so the same public functions stay usable under ``jit`` and
``vmap``, where the caller is responsible for the values.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import jax
import numpy as np

G_MAX = 8  # goal slots in every scene
#: The largest magnitude float32 holds (about 3.4e38). The project computes in float32 (the
#: networks, the study, P_pop, the planner), so a number read from a file beyond it (which
#: float32 would make ±inf) is refused: :func:`check_float32`.
FLOAT32_MAX = float(np.finfo(np.float32).max)


#: Seeds are integers 0 ≤ seed < 2**32. ``jax.random.key`` keeps a seed's low 32 bits
#: (with 64-bit types off, the project's setting): 2**32 draws what 0 draws, −1 what
#: 2**32 − 1 draws, and from 2**63 it raises OverflowError; ``jax.random.fold_in`` refuses
#: data of 2**32 or more. (Measured with jax 0.10.)
SEED_LIMIT = 2**32


def check_seeds(name: str, first, count: int = 1, *, count_name: str | None = None) -> None:
    """Raise unless the seeds ``first`` … ``first + count − 1`` are integers in
    0 … 2**32 − 1 (:data:`SEED_LIMIT`). ``name`` names ``first`` (a flag: ``--first-seed``)
    and ``count_name`` the flag of ``count`` (``--seeds``); a ``count`` below 1 is left to
    its own check.

    >>> check_seeds("--seed", 2**32)  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ValueError: --seed 4294967296: expected a seed in 0..4294967295 (2**32 - 1: ...)
    """
    if not (isinstance(first, int | np.integer) and not isinstance(first, bool)) or not (
        0 <= first < SEED_LIMIT
    ):
        raise ValueError(
            f"{name} {first!r}: expected a seed in 0..{SEED_LIMIT - 1} (2**32 - 1: "
            "jax.random.key keeps 32 bits, so 2**32 would draw what 0 draws)"
        )
    if count >= 1 and first + count > SEED_LIMIT:
        raise ValueError(
            f"{name} {first}, {count_name or 'count'} {count}: the last seed, "
            f"{first + count - 1}, is beyond 2**32 - 1 ({SEED_LIMIT - 1}); expected {name} "
            f"at most {SEED_LIMIT - count}"
        )


def is_concrete(x) -> bool:
    """True if ``x`` holds values now (not a tracer inside jit/vmap/grad)."""
    return not isinstance(x, jax.core.Tracer)


def check_shape(name: str, x, shape: Sequence[int | None]) -> None:
    """Raise unless ``x.shape`` matches ``shape`` (``None`` matches any size)."""
    got = tuple(np.shape(x))
    if len(got) != len(shape) or any(
        s is not None and s != g for s, g in zip(shape, got, strict=True)
    ):
        want = "(" + ", ".join("*" if s is None else str(s) for s in shape) + ")"
        raise ValueError(f"{name}: expected shape {want}, got {got}")


def check_finite(name: str, x) -> None:
    """Raise if a concrete ``x`` holds NaN or ±inf."""
    if is_concrete(x):
        a = np.asarray(x)
        if a.dtype.kind in "fc" and not np.all(np.isfinite(a)):
            bad = int(np.size(a) - np.count_nonzero(np.isfinite(a)))
            raise ValueError(f"{name}: expected finite values, found {bad} NaN/inf entries")


def check_float32(name: str, x) -> None:
    """Raise if a concrete ``x`` holds a finite value of magnitude over :data:`FLOAT32_MAX`
    (a float64 number that would become ±inf in float32); NaN and ±inf are left to
    :func:`check_finite`. Names the first such value and its index."""
    if not is_concrete(x):
        return
    a = np.asarray(x)
    if a.dtype.kind != "f" or np.finfo(a.dtype).max <= FLOAT32_MAX:
        return  # float32 or narrower holds every finite value; integers are checked by range
    over = np.argwhere(np.isfinite(a) & (np.abs(a) > FLOAT32_MAX))
    if len(over):
        idx = tuple(int(v) for v in over[0])
        raise ValueError(
            f"{name}: expected magnitudes at most {FLOAT32_MAX:.4g} (float32), found "
            f"{float(a[idx])!r} at index {list(idx)}"
        )


def check_finite_result(name: str, y, why: str) -> None:
    """Raise, naming the input ``name``, if a concrete result ``y`` holds NaN or ±inf.

    For finite inputs whose result still overflows (``why`` says how); under
    ``jit``/``vmap`` (a traced ``y``) nothing is checked.
    """
    if is_concrete(y) and not np.all(np.isfinite(np.asarray(y))):
        raise ValueError(f"{name}: {why}")


def check_real(name: str, x) -> None:
    """Raise unless ``x`` holds real numbers (integer or floating dtype): complex values
    would lose their imaginary part, strings and objects are not coordinates."""
    dtype = np.dtype(x.dtype) if hasattr(x, "dtype") else np.asarray(x).dtype
    if dtype.kind not in "iuf":
        raise ValueError(f"{name}: expected real numbers, got dtype {dtype}")


def check_array(name: str, x, shape: Sequence[int | None]) -> None:
    """Shape, dtype (real numbers) and finiteness check."""
    check_shape(name, x, shape)
    check_real(name, x)
    check_finite(name, x)


def _scalar_text(value) -> str:
    """``value`` for a message: a NumPy scalar as a plain number, not ``np.float64(0.25)``."""
    return repr(value.item()) if isinstance(value, np.generic) else repr(value)


def check_positive(name: str, value) -> None:
    """Raise unless a concrete scalar is a real, finite number > 0 (not a string, a bool
    or a complex number)."""
    if is_concrete(value):
        v = np.asarray(value)
        if isinstance(value, bool) or v.dtype.kind not in "iuf":
            raise ValueError(
                f"{name}: expected a finite number > 0, got {_scalar_text(value)} "
                f"({type(value).__name__})"
            )
        if v.ndim != 0 or not np.isfinite(v) or not v > 0:
            raise ValueError(f"{name}: expected a finite number > 0, got {_scalar_text(value)}")


def check_goal_mask(name: str, goal_mask, *, batch_shape: tuple[int, ...] = ()) -> None:
    """A goal mask has G_MAX boolean slots, at least one real goal, and real goals first."""
    check_shape(name, goal_mask, (*batch_shape, G_MAX))
    if not is_concrete(goal_mask):
        return
    m = np.asarray(goal_mask)
    if m.dtype != np.bool_:
        if m.dtype.kind not in "iuf":
            raise ValueError(f"{name}: expected booleans (or 0/1), got dtype {m.dtype}")
        if not np.all((m == 0) | (m == 1)):
            bad = np.unique(m[(m != 0) & (m != 1)])[:3].tolist()
            raise ValueError(f"{name}: expected booleans (or 0/1), found the value(s) {bad}")
        m = m.astype(bool)
    # An elementwise fold over the slots: much faster than a reduction over a short axis.
    if not functools.reduce(np.logical_or, [m[..., k] for k in range(G_MAX)]).all():
        raise ValueError(f"{name}: expected 1..{G_MAX} real goals, found a mask with none")


#: Metres: two real goals nearer than this share one position (and are refused).
SAME_POSITION = 1e-9


def check_goals(name: str, goals, goal_mask, *, batch_shape: tuple[int, ...] = ()) -> None:
    """Goals are finite (G_MAX, 3) arrays; real goals must be pairwise distinct (at least
    :data:`SAME_POSITION` apart)."""
    check_array(name, goals, (*batch_shape, G_MAX, 3))
    check_goal_mask("goal_mask", goal_mask, batch_shape=batch_shape)
    if not (is_concrete(goals) and is_concrete(goal_mask)):
        return
    g = np.asarray(goals, np.float64).reshape(-1, G_MAX, 3)
    m = np.asarray(goal_mask, bool).reshape(-1, G_MAX)
    d = np.linalg.norm(g[:, :, None] - g[:, None, :], axis=-1)
    pair = m[:, :, None] & m[:, None, :] & ~np.eye(G_MAX, dtype=bool)
    if np.any(pair & (d < SAME_POSITION)):
        raise ValueError(f"{name}: two real goals share the same position")


def check_labels(name: str, labels, goal_mask, *, atol: float = 1e-4) -> None:
    """Labels are probability vectors over the real goals: finite, ≥ 0, summing to 1
    (within ``atol``) over real goals and exactly 0 on padded slots."""
    check_array(name, labels, np.shape(goal_mask))
    if not (is_concrete(labels) and is_concrete(goal_mask)):
        return
    y = np.asarray(labels, np.float64)
    m = np.asarray(goal_mask, bool)
    if np.any(y < 0):
        raise ValueError(
            f"{name}: expected probabilities >= 0, found {int(np.sum(y < 0))} negative"
        )
    if np.any(y[~m] != 0):
        raise ValueError(f"{name}: expected 0 on padded goal slots, found non-zero entries")
    s = y.sum(-1)
    bad = np.abs(s - 1.0) > atol
    if np.any(bad):
        i = int(np.argmax(bad))
        raise ValueError(
            f"{name}: expected each row to sum to 1 over real goals, "
            f"row {i} sums to {s.flat[i]:.6g}"
        )
