"""Study files: one ``.npz`` per study (:ref:`concepts-populations`), written atomically and read
with ``allow_pickle=False``.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from slotv_jax.answers.format import FORMAT, Study, _Where, make_study
from slotv_jax.core import fileio
from slotv_jax.core.fileio import atomic_write

# ---------------------------------------------------------------- file I/O


def save_study(path: str | os.PathLike, study: Study) -> Path:
    """Write ``study`` as one ``.npz`` (atomically: a reader never sees a partial file)."""
    path = Path(path)
    n = study.n_trajectories
    arrays: dict[str, np.ndarray] = {
        "format": np.array(FORMAT),
        "xyz": study.xyz.astype(np.float32),
        "length": study.length.astype(np.int32),
        "goals": (study.goals[0] if study.shared_goals else study.goals).astype(np.float32),
        "goal_mask": study.goal_mask[0] if study.shared_goals else study.goal_mask,
        "trajectory_ids": np.array(study.trajectory_ids or [str(i) for i in range(n)], str),
        "answer_trajectory": study.answer_trajectory.astype(np.int32),
        "answer_tau": study.answer_tau.astype(np.float64),
        "counts": study.counts.astype(np.float64),
    }
    if study.t is not None:
        arrays["t"] = study.t.astype(np.float64)
    if study.goal_names is not None:
        arrays["goal_names"] = study.goal_names[0] if study.shared_goals else study.goal_names
    if study.answer_condition is not None:
        arrays["answer_condition"] = study.answer_condition.astype(np.int32)
        arrays["conditions"] = np.array(study.conditions, str)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(path, lambda f: np.savez_compressed(f, **arrays))
    return path


_NPZ_FIELDS = {
    "xyz", "length", "t", "goals", "goal_mask", "goal_names", "trajectory_ids",
    "answer_trajectory", "answer_tau", "counts", "probs", "n_answers", "answer_condition",
    "conditions", "format",
}  # fmt: skip


def load_study(path: str | os.PathLike) -> Study:
    """Read and validate a study ``.npz`` (no pickle). Raises ValueError naming the file,
    the field and the row on anything :func:`make_study` rejects, a corrupt file, or
    unknown or missing arrays."""
    path = Path(path)
    w = _Where(str(path))
    arrays = fileio.load_npz(path)  # names a missing, truncated or non-zip file
    fmt = str(arrays.pop("format", ""))
    if fmt != FORMAT:
        raise ValueError(f"{w('format')}: expected {FORMAT!r}, got {fmt!r}")
    unknown = sorted(set(arrays) - _NPZ_FIELDS)
    if unknown:
        raise ValueError(f"{w(unknown[0])}: unknown array (known: {sorted(_NPZ_FIELDS)})")
    for req in ("xyz", "goals", "goal_mask", "answer_trajectory"):
        if req not in arrays:
            raise ValueError(f"{w(req)}: missing")
    cond_names = arrays.pop("conditions", None)
    ids = arrays.pop("trajectory_ids", None)
    return make_study(
        arrays.pop("xyz"),
        arrays.pop("goals"),
        arrays.pop("goal_mask"),
        arrays.pop("answer_trajectory"),
        arrays.pop("counts", None),
        conditions=() if cond_names is None else [str(c) for c in cond_names],
        trajectory_ids=() if ids is None else [str(c) for c in ids],
        source=str(path),
        **arrays,
    )
