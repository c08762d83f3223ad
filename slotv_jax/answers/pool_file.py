"""The researcher's pool as a folder: the observer that the people loop's ``pick`` plans
against, fitted on a study, for a planner (``python -m slotv_jax.study pick --by pool``).

The pool is log-linear (Genest & Zidek 1986, "Combining probability distributions: a
critique and an annotated bibliography", Statistical Science 1(1)):

    P_w(g | ξ) ∝ Π_f P_f(g | ξ)^{w_f},   logits_w = Σ_f w_f log P_f(g | ξ)

over the members f with weight w_f > 0, each log-probability floored at log
:data:`~slotv_jax.answers.format.PROB_FLOOR` (:func:`slotv_jax.answers.pooling.pooled_logits`,
the loop's own pool). The weights are those fitted on the held-out answers
(:func:`slotv_jax.answers.pooling.fit_pool_weights`); the members are fitted on every answer.

The folder::

    DIR/pool.json            format, version, camera, members [{name, weight, and either
                             checkpoint (a folder under DIR) or labeler and beta}], meta
    DIR/members/NAME/        each learned member's checkpoint (slotv_jax.load_observer)
    DIR/camera.json          the lab's camera file, when the pool's camera is one
                             (a relative "camera" path is read from DIR)

:func:`load_pool` reads it back as one observer ``(xyz (T, 3), goals (8, 3), goal_mask (8,))
-> logits (8,)`` with ``prefix`` (what :func:`slotv_jax.planning.make_planner` plans
against). JSON and Orbax only: no pickle.
"""

from __future__ import annotations

import json
import math
import os
import shutil
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from slotv_jax import planning
from slotv_jax.answers.format import PROB_FLOOR
from slotv_jax.answers.pick import LABELERS
from slotv_jax.answers.pooling import pool_observer
from slotv_jax.core import fileio
from slotv_jax.core.validation import FLOAT32_MAX
from slotv_jax.training import checkpoint
from slotv_jax.world.scene import CAMERAS, check_camera, is_camera_file

POOL_FILE = "pool.json"
FORMAT = "slotv_jax observer pool"
VERSION = 1
MEMBERS_DIR = "members"
#: The smallest weight or β a pool file may hold: float32's smallest normal number, so that a
#: positive value stays positive (and not subnormal) in the float32 pool.
FIELD_MIN = float(np.finfo(np.float32).tiny)
#: The largest sum of the weights: the pooled logits ``Σ_f w_f ℓ_f`` have ``ℓ_f`` floored at
#: log PROB_FLOOR (−27.6), so ``|logits| ≤ 27.6 · Σ_f w_f``; at most half of float32's largest
#: value (a margin for float32 rounding) keeps every logit, and every probability, finite:
#: Σ w ≤ 6.2e36. (A weight of 1e300 is inf in float32, and inf · 0 = NaN.)
WEIGHT_SUM_MAX = FLOAT32_MAX / (2 * -math.log(PROB_FLOOR))
#: The largest score a labeler member is taken to see: 1e7 (metres for dragan and effdist;
#: image-plane units for nikolaidis, a point 10 m aside at the least depth it sees, 1e-6;
#: metres per unit of the motion's normalised time for fastapp's approach speed, 10 m in a
#: step of 1e-6). The bound the population model puts on its people's temperatures.
SCORE_MAX = 1e7
#: The largest β of a labeler member: β · score stays finite in float32 for every score up
#: to :data:`SCORE_MAX` (3.4e31; beyond it a labeler's labels overflow).
BETA_MAX = FLOAT32_MAX / SCORE_MAX

__all__ = ["POOL_FILE", "is_pool", "load_pool", "pool_observer", "save_pool"]


def is_pool(path: str | os.PathLike) -> bool:
    """True if ``path`` is a folder holding ``pool.json``."""
    return (Path(path) / POOL_FILE).is_file()


CAMERA_FILE = "camera.json"  # a pool's copy of the lab's camera file (when it has one)


def save_pool(
    out: str | os.PathLike,
    members: Mapping[str, Mapping[str, Any]],
    weights: Mapping[str, float],
    *,
    camera: str = "observer",
    meta: Mapping[str, Any] | None = None,
) -> list[str]:
    """Write the pool of ``members`` (``{name: {"cfg", "state"}}`` for a learned family,
    ``{name: {"beta"}}`` for a labeler, as :func:`slotv_jax.answers.pick.fit_candidates`
    returns them) with ``weights`` (``{name: w}``) into the folder ``out``, new or empty
    (made; the caller writes it beside its target and swaps it in). Members of weight 0
    are left out; returns the names written. ValueError, before anything is written, if no
    weight is positive or ``out`` holds files."""
    kept = [n for n, w in weights.items() if float(w) > 0]
    if not kept:
        raise ValueError("the pool's weights are all 0: no observer to plan with")
    out = Path(out)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise ValueError(f"out: expected a new or empty folder, {out} holds files")
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for name in kept:
        fit, w = members[name], float(weights[name])
        if "beta" in fit:
            rows.append({"name": name, "weight": w, "labeler": name, "beta": float(fit["beta"])})
        else:
            rel = f"{MEMBERS_DIR}/{name}"
            checkpoint.save(out / rel, fit["cfg"], fit["state"])
            rows.append({"name": name, "weight": w, "checkpoint": rel})
    if is_camera_file(camera):  # the lab's camera travels with the pool: a copy beside it
        check_camera(camera)
        shutil.copyfile(camera, out / CAMERA_FILE)
        camera = CAMERA_FILE
    doc = {"format": FORMAT, "version": VERSION, "camera": camera, "members": rows,
           "meta": dict(meta or {})}  # fmt: skip
    fileio.write_text(out / POOL_FILE, json.dumps(doc, indent=1, allow_nan=False) + "\n")
    return kept


def _field(where: Path, name: str, msg: str) -> ValueError:
    return ValueError(f"{where}: field {name!r}: {msg}")


def _positive(where: Path, name: str, v: Any, most: float, why: str) -> float:
    """``v`` as a float if it is a number (not a bool) in [:data:`FIELD_MIN`, ``most``], else
    the field's error (``why``: what the upper bound keeps finite)."""
    if isinstance(v, bool) or not isinstance(v, int | float) or not FIELD_MIN <= v <= most:
        raise _field(
            where,
            name,
            f"expected a number in [{FIELD_MIN:.3g}, {most:.3g}] ({why}), got {v!r}",
        )
    return float(v)


def load_pool(path: str | os.PathLike):
    """The pool in folder ``path`` (:func:`save_pool`) as one observer with ``prefix``
    (:func:`pool_observer`): its ``config`` holds the members' names, its
    ``params["weights"]`` their weights. Every field is checked before any member is
    loaded: ValueError naming ``pool.json`` and the field (``members[i].weight`` ...).
    The bounds keep the pool finite in float32: each weight and β at least
    :data:`FIELD_MIN`, the weights' sum at most :data:`WEIGHT_SUM_MAX`, a labeler's β at
    most :data:`BETA_MAX`; the names distinct; ``meta`` an object."""
    path = Path(path)
    where = path / POOL_FILE
    if not where.is_file():
        raise FileNotFoundError(f"{path}: no {POOL_FILE} (not a pool of observers)")
    doc = fileio.read_json(where)
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise _field(where, "format", f"expected {FORMAT!r}, got {_get(doc, 'format')!r}")
    if doc.get("version") != VERSION:
        raise _field(where, "version", f"expected {VERSION}, got {doc.get('version')!r}")
    camera = doc.get("camera")
    if is_camera_file(camera):
        # a camera file: beside the pool file, or where a relative path leads from it
        camera = str(Path(camera) if Path(camera).is_absolute() else (path / camera))
        try:
            check_camera(camera)
        except ValueError as e:
            raise _field(where, "camera", str(e)) from None
    elif camera not in CAMERAS:
        raise _field(
            where, "camera", f"expected one of {CAMERAS} or a camera file (*.json), got {camera!r}"
        )
    rows = doc.get("members")
    if not isinstance(rows, list) or not rows:
        raise _field(where, "members", "expected a non-empty list of members")
    specs = []
    root = path.resolve()
    for i, r in enumerate(rows):
        at = f"members[{i}]"
        if not isinstance(r, dict) or not isinstance(r.get("name"), str):
            raise _field(where, at, "expected an object with a string 'name'")
        if r["name"] in {n for n, _, _ in specs}:
            raise _field(where, f"{at}.name", f"expected distinct names, {r['name']!r} repeats")
        why = "the pooled logits finite in float32"
        w = _positive(where, f"{at}.weight", r.get("weight"), WEIGHT_SUM_MAX, why)
        if ("checkpoint" in r) == ("labeler" in r):
            raise _field(where, at, "expected either 'checkpoint' or 'labeler' and 'beta'")
        if "labeler" in r:
            if r["labeler"] not in LABELERS:
                raise _field(where, f"{at}.labeler", f"expected one of {LABELERS}, "
                             f"got {r['labeler']!r}")  # fmt: skip
            why = f"β times a score up to {SCORE_MAX:g} finite in float32"
            b = _positive(where, f"{at}.beta", r.get("beta"), BETA_MAX, why)
            specs.append((r["name"], w, ("labeler", r["labeler"], b)))
        else:
            rel = r["checkpoint"]
            target = (path / rel).resolve() if isinstance(rel, str) else None
            if target is None or not target.is_relative_to(root) or target == root:
                raise _field(where, f"{at}.checkpoint",
                             f"expected a folder inside {path}, got {rel!r}")  # fmt: skip
            if not checkpoint.exists(target):
                raise _field(where, f"{at}.checkpoint", f"no checkpoint at {path / rel}")
            specs.append((r["name"], w, ("checkpoint", target)))
    total = math.fsum(w for _, w, _ in specs)
    if total > WEIGHT_SUM_MAX:
        raise _field(
            where,
            "members",
            f"the weights sum to {total:.3g}, expected at most {WEIGHT_SUM_MAX:.3g} (the "
            "pooled logits finite in float32)",
        )
    meta = doc.get("meta", {})
    if not isinstance(meta, dict):
        raise _field(where, "meta", f"expected an object, got {type(meta).__name__}")
    observers = []
    for _, _, spec in specs:
        if spec[0] == "labeler":
            observers.append(planning.labeler_observer(spec[1], beta=spec[2], camera=camera))
        else:
            observers.append(checkpoint.load_observer(spec[1]))
    return pool_observer(observers, [w for _, w, _ in specs], [n for n, _, _ in specs])


def _get(doc: Any, key: str) -> Any:
    return doc.get(key) if isinstance(doc, dict) else type(doc).__name__
