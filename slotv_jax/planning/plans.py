"""The plans file: every planner's plan of a few planning problems, in one ``.npz``.

Written by the planning experiment (``OUT/plans.npz``: its example problems,
:func:`slotv_jax.experiments.planning.examples.saved_plans`) and the people loop
(``STEM_plans.npz``: its example problem); read by ``python -m slotv_jax.render --plans``,
``python -m slotv_jax.study stimuli --plans`` and the planning experiment's figures. It is
read with ``allow_pickle=False`` (no object arrays). P problems, K planners, T points::

    goals      (P, 8, 3)    float32   goal positions (m)                      required
    goal_mask  (P, 8)       bool      real goal slots                         required
    target     (P,)         int       the goal slot moved to                  required
    names      (K,)         unicode   the planners                            required
    q          (K, P, T, 7) float32   planner k's plan of problem p: joint    required
                                      configurations (rad); a row with NaN: no plan
    xyz        (K, P, T, 3) float32   its executed TCP path FK(q) (m)         optional
    y          (K, P, 8)    float32   its labels under the scoring labeler    optional

The planning experiment adds, per problem: ``family`` (the labeler family: dragan or
nikolaidis), ``beta`` (the temperature that scored the row), ``problem`` (its index in
the run), ``split`` and ``scene`` (where its scene comes from).

Every reader gets the file checked (:func:`load_plans`, :func:`check_plans`): an error names
the file and the array before any work.

>>> import numpy as np, tempfile, os
>>> P, K, T = 2, 3, 5
>>> goals = np.zeros((P, 8, 3), np.float32); goals[:, :3, 0] = [0.4, 0.5, 0.6]
>>> plans = {"goals": goals, "goal_mask": np.arange(8) < [[2], [3]],
...          "target": np.zeros(P, np.int32), "names": np.array(["straight", "oracle", "slotv"]),
...          "q": np.zeros((K, P, T, 7), np.float32)}
>>> path = os.path.join(tempfile.mkdtemp(), "plans.npz")
>>> save_plans(path, plans)
>>> sorted(load_plans(path))
['goal_mask', 'goals', 'names', 'q', 'target']
"""

from __future__ import annotations

import os
from collections.abc import Mapping

import numpy as np

from slotv_jax.core import validation
from slotv_jax.core.fileio import atomic_write, load_npz

__all__ = ["EXTRAS", "REQUIRED", "check_plans", "load_plans", "save_plans"]

REQUIRED = ("goals", "goal_mask", "target", "names", "q")  # the arrays every plans file has
EXTRAS = ("family", "beta", "problem", "split", "scene")  # optional, one entry per problem


def check_plans(plans: Mapping[str, np.ndarray], where: str) -> None:
    """Raise ValueError naming ``where`` (e.g. ``--plans FILE``) and the array unless
    ``plans`` is a plans file every reader can use (the module docstring's format):

    - the required arrays, of the shapes above, with at least one planner (``names``, each
      named once), one problem and two points per plan (``q``);
    - ``q``, ``xyz``, ``y``: real numbers that float32 holds (a NaN row of ``q``: no plan),
      at least one plan in the file, and ``xyz`` finite wherever ``q`` is a plan;
    - ``goals`` and ``goal_mask`` each problem's scene (finite goals, 1..8 real ones, no two
      at one position), ``target`` a real goal of each;
    - the per-problem extras (``family``, ``beta``, ``problem``, ``split``, ``scene``) one
      entry per problem.
    """
    missing = [k for k in REQUIRED if k not in plans]
    if missing:
        raise ValueError(f"{where}: missing arrays {missing}; it holds {sorted(plans)}")
    q, names = np.asarray(plans["q"]), np.asarray(plans["names"])
    if names.ndim != 1 or names.dtype.kind != "U":
        raise ValueError(f"{where}: names: expected (K,) strings, got {names.dtype} {names.shape}")
    K = len(names)
    if K == 0:
        raise ValueError(f"{where}: names: expected at least one planner, got none")
    twice = [n for n in dict.fromkeys(names.tolist()) if names.tolist().count(n) > 1]
    if twice:
        raise ValueError(f"{where}: names: expected each planner once, {twice[0]!r} is twice")
    if q.ndim != 4 or q.shape[0] != K or q.shape[-1] != 7:
        raise ValueError(f"{where}: q: expected (K={K}, P, T, 7), got {q.shape}")
    P, T = q.shape[1], q.shape[2]
    if P == 0:
        raise ValueError(f"{where}: q: expected at least one problem (P >= 1), got {q.shape}")
    if T < 2:
        raise ValueError(f"{where}: q: expected at least 2 points per plan (T >= 2), got {q.shape}")
    want = {"goals": (P, 8, 3), "goal_mask": (P, 8), "target": (P,), "xyz": (K, P, T, 3),
            "y": (K, P, 8)}  # fmt: skip
    for k, shape in want.items():
        if k in plans and np.shape(plans[k]) != shape:
            raise ValueError(f"{where}: {k}: expected {shape}, got {np.shape(plans[k])}")
    for k in EXTRAS:
        if k in plans and (np.ndim(plans[k]) != 1 or len(plans[k]) != P):
            raise ValueError(
                f"{where}: {k}: expected one entry per problem, shape ({P},), got "
                f"{np.shape(plans[k])}"
            )
    for k in ("q", "xyz", "y", "goals"):
        if k in plans:
            try:
                validation.check_real(k, plans[k])
                validation.check_float32(k, plans[k])
            except ValueError as e:
                raise ValueError(f"{where}: {e}") from None
    planned = np.isfinite(q).all(axis=(2, 3))  # (K, P): a row with a NaN is no plan
    if not planned.any():
        raise ValueError(f"{where}: q: no plan in the file (every row holds NaN)")
    if "xyz" in plans:
        bad = planned & ~np.isfinite(np.asarray(plans["xyz"])).all(axis=(2, 3))
        if bad.any():
            k, p = np.argwhere(bad)[0]
            raise ValueError(
                f"{where}: xyz: expected finite points where q is a plan, planner "
                f"{str(names[k])!r} of problem {p} holds NaN/inf"
            )
    try:
        validation.check_goals("goals", plans["goals"], plans["goal_mask"], batch_shape=(P,))
    except ValueError as e:
        raise ValueError(f"{where}: {e}") from None
    target, mask = np.asarray(plans["target"]), np.asarray(plans["goal_mask"], bool)
    if target.dtype.kind not in "iu" or not all(
        0 <= t < 8 and mask[p, t] for p, t in enumerate(target.tolist())
    ):
        raise ValueError(f"{where}: target: expected the index of a real goal of each problem")


def load_plans(path: str | os.PathLike, flag: str = "--plans") -> dict[str, np.ndarray]:
    """The arrays of a plans file, checked (:func:`check_plans`; errors name ``flag``)."""
    plans = load_npz(path)
    check_plans(plans, f"{flag} {path}")
    return plans


def save_plans(path: str | os.PathLike, plans: Mapping[str, np.ndarray]) -> None:
    """Check ``plans`` and write them, compressed, atomically (never a half-written file)."""
    arrays = {k: np.asarray(v) for k, v in plans.items()}
    check_plans(arrays, f"plans for {path}")
    atomic_write(path, lambda f: np.savez_compressed(f, **arrays))
