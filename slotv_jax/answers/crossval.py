"""Evaluation on a study: per-row metrics, the hand-crafted labelers as observers (with a
fitted β) and cross-validation against them.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Float
from tqdm.auto import tqdm

from slotv_jax.answers.fitting import answer_logits, train_study
from slotv_jax.answers.format import BETA_RANGE, PROB_FLOOR, Study
from slotv_jax.core import validation
from slotv_jax.core.shapes import bucket, pad_rows
from slotv_jax.core.validation import G_MAX
from slotv_jax.observers import labelers
from slotv_jax.training.config import TrainConfig
from slotv_jax.world import scene

# ============================================================== evaluation


def row_metrics(logits: np.ndarray, goal_mask: np.ndarray, counts: np.ndarray) -> dict:
    """Accuracy and likelihood of per-row goal logits (−∞ on padding) against counts.

    - ``accuracy``: fraction of rows whose argmax equals the modal answer (ties: the
      lowest slot, as :ref:`concepts-metrics` breaks them);
    - ``answer_accuracy``: fraction of all answers that equal the argmax;
    - ``nll_per_answer``: −Σ c log p / Σ c (nats).
    """
    logits = np.asarray(logits, np.float64)
    counts = np.asarray(counts, np.float64)
    mask = np.asarray(goal_mask, bool)
    z = np.where(mask, logits, -np.inf)
    z = z - z.max(-1, keepdims=True)
    logp = np.where(mask, z - np.log(np.exp(z).sum(-1, keepdims=True)), 0.0)
    pred = np.argmax(z, -1)
    mode = np.argmax(np.where(mask, counts, -np.inf), -1)
    rows = np.arange(len(counts))
    return {
        "accuracy": float(np.mean(pred == mode)),
        "answer_accuracy": float(counts[rows, pred].sum() / counts.sum()),
        "nll_per_answer": float(-np.sum(np.where(counts > 0, counts * logp, 0.0)) / counts.sum()),
        "rows": len(counts),
        "answers": float(counts.sum()),
    }


def model_metrics(cfg: TrainConfig, params, study: Study) -> dict:
    """:func:`row_metrics` of a trained model on every answer row of ``study``."""
    logits = answer_logits(cfg, params, study)
    g = logits.shape[-1]
    return row_metrics(logits, study.goal_mask[study.answer_trajectory, :g], study.counts[:, :g])


@functools.cache
def _jit_labeler(name: str, camera: str, with_t: bool):
    cam = scene.camera(camera) if name == "nikolaidis" else None

    def one(xyz, goals, mask, beta, t):
        kw = {"beta": beta, "t": t if with_t else None}
        if name == "nikolaidis":
            return labelers.nikolaidis(xyz, goals, mask, cam, **kw)
        return labelers.LABELERS[name](xyz, goals, mask, **kw)

    return jax.jit(jax.vmap(one, in_axes=(0, 0, 0, None, 0)))


def labeler_probs(
    study: Study, name: str, *, beta: float | None = None, camera: str = "observer"
) -> Float[np.ndarray, "A 8"]:
    """The hand-crafted observer ``name``'s goal distribution for every answer row, computed
    on the points the row's participants saw (``xyz[:L]``, and ``t[:L]`` if the study has
    time stamps). ``beta`` defaults to the labeler's SPEC value. Rows are grouped by L; each
    L compiles once per labeler (β is traced, so fitting it does not recompile).
    """
    if name not in labelers.LABELERS:
        raise ValueError(f"labeler: expected one of {list(labelers.LABELERS)}, got {name!r}")
    beta = labelers.DEFAULT_BETAS[name] if beta is None else float(beta)
    validation.check_positive("beta", beta)
    f = _jit_labeler(name, camera, study.t is not None)
    seen = study.seen()
    traj = study.answer_trajectory
    out = np.zeros((study.n_rows, G_MAX), np.float64)
    for L in np.unique(seen):
        rows = np.flatnonzero(seen == L)
        tr = pad_rows(traj[rows], bucket(rows.size))  # a few shapes, not one per study size
        t = study.t[tr, :L] if study.t is not None else np.zeros((tr.size, L))
        y = f(study.xyz[tr, :L], study.goals[tr], study.goal_mask[tr], jnp.float32(beta), t)
        out[rows] = np.asarray(y, np.float64)[: rows.size]
    return out


def labeler_visible(study: Study, camera: str = "observer") -> bool:
    """Whether every point and real goal is in front of ``camera`` (Nikolaidis needs it)."""
    cam = scene.camera(camera)
    ok = jax.jit(jax.vmap(labelers.depth_ok, in_axes=(0, 0, 0, None)))(
        study.xyz, study.goals, study.goal_mask, cam
    )
    # padded points sit at the origin, which is in front of every scene camera
    return bool(np.all(np.asarray(ok)))


def _nll(probs: np.ndarray, counts: np.ndarray) -> float:
    logp = np.log(np.maximum(probs, PROB_FLOOR))
    return float(-np.sum(np.where(counts > 0, counts * logp, 0.0)) / counts.sum())


def fit_beta(
    study: Study, name: str, *, camera: str = "observer", tol: float = 1e-3
) -> tuple[float, float]:
    """β of labeler ``name`` that maximises the likelihood of ``study``'s counts.

    A 1-D search on log β within [β₀/100, β₀·100] (β₀ the SPEC default): a grid of 17
    points, then golden-section search (Kiefer 1953) on the bracket around the best grid
    point until it is ``tol`` wide in log β. Returns (β, NLL per answer at β).
    """
    b0 = labelers.DEFAULT_BETAS[name]
    lo, hi = math.log(b0 / BETA_RANGE), math.log(b0 * BETA_RANGE)
    cache: dict[float, float] = {}

    def nll(lb: float) -> float:
        if lb not in cache:
            cache[lb] = _nll(labeler_probs(study, name, beta=math.exp(lb), camera=camera),
                             study.counts)  # fmt: skip
        return cache[lb]

    grid = np.linspace(lo, hi, 17)
    vals = [nll(float(g)) for g in grid]
    j = int(np.argmin(vals))
    a, b = float(grid[max(j - 1, 0)]), float(grid[min(j + 1, len(grid) - 1)])
    r = (math.sqrt(5) - 1) / 2
    c, d = b - r * (b - a), a + r * (b - a)
    while b - a > tol:
        if nll(c) <= nll(d):
            b, d = d, c
            c = b - r * (b - a)
        else:
            a, c = c, d
            d = a + r * (b - a)
    best = min(cache, key=cache.get)
    return math.exp(best), cache[best]


def cross_validate(
    cfg: TrainConfig | Mapping[str, TrainConfig],
    study: Study,
    *,
    folds: int = 5,
    seed: int = 0,
    baselines: Sequence[str] = tuple(labelers.LABELER_NAMES),
    camera: str = "observer",
    progress: bool = True,
) -> dict:
    """k-fold cross-validation by trajectory (every answer row of a trajectory in one fold).

    For each fold, each config in ``cfg`` (one, or a mapping name -> config) trains on the
    other folds, and each hand-crafted labeler in ``baselines`` gets its β fitted on them
    (:func:`fit_beta`); all are scored on the held-out rows with :func:`row_metrics`. The
    uniform guess is scored too (its accuracy is the chance level, the mean of 1/n_goals).
    Returns {"folds", "per_fold": [...], "<name>": pooled metrics} where the pooled
    metrics weight each fold by its rows (accuracy) or answers (NLL, answer accuracy).
    Nikolaidis is skipped (with a note) if a point lies behind the camera.
    """
    cfgs = {cfg.method: cfg} if isinstance(cfg, TrainConfig) else dict(cfg)
    n = study.n_trajectories
    if not 2 <= folds <= n:
        raise ValueError(f"folds: expected 2 <= folds <= {n} (trajectories), got {folds}")
    base = list(baselines)
    notes = {}
    if "nikolaidis" in base and not labeler_visible(study, camera):
        base.remove("nikolaidis")
        notes["nikolaidis"] = f"skipped: a point or goal lies behind camera {camera!r}"
    order = np.random.default_rng(seed).permutation(n)
    fold_of = np.empty(n, np.int32)
    fold_of[order] = np.arange(n) % folds
    per_fold = []
    bar = tqdm(total=folds, desc="cross-validation", unit="fold", disable=not progress)
    for f in range(folds):
        tr_idx, te_idx = np.flatnonzero(fold_of != f), np.flatnonzero(fold_of == f)
        tr, te = study.select_trajectories(tr_idx), study.select_trajectories(te_idx)
        res: dict[str, Any] = {"fold": f, "train_rows": tr.n_rows, "test_rows": te.n_rows}
        for name, c in cfgs.items():
            state = train_study(c, tr, jax.random.key(seed * 1000 + f), progress=False)
            res[name] = model_metrics(c, state.params, te)
        uni = np.where(te.goal_mask[te.answer_trajectory], 0.0, -np.inf)
        res["uniform"] = row_metrics(uni, te.goal_mask[te.answer_trajectory], te.counts)
        res["uniform"]["accuracy"] = float(
            np.mean(1.0 / te.goal_mask[te.answer_trajectory].sum(-1))
        )
        for name in base:
            beta, _ = fit_beta(tr, name, camera=camera)
            y = labeler_probs(te, name, beta=beta, camera=camera)
            with np.errstate(divide="ignore"):
                logits = np.log(np.maximum(y, PROB_FLOOR))
            res[name] = {**row_metrics(logits, te.goal_mask[te.answer_trajectory], te.counts),
                         "beta": beta}  # fmt: skip
        per_fold.append(res)
        bar.update(1)
    bar.close()
    out: dict[str, Any] = {"folds": folds, "seed": seed, "per_fold": per_fold, "notes": notes}
    for name in [*cfgs, "uniform", *base]:
        rows = np.array([r[name]["rows"] for r in per_fold], np.float64)
        ans = np.array([r[name]["answers"] for r in per_fold], np.float64)
        pooled = {
            "accuracy": float(np.sum(rows * [r[name]["accuracy"] for r in per_fold]) / rows.sum()),
            "answer_accuracy": float(
                np.sum(ans * [r[name]["answer_accuracy"] for r in per_fold]) / ans.sum()
            ),
            "nll_per_answer": float(
                np.sum(ans * [r[name]["nll_per_answer"] for r in per_fold]) / ans.sum()
            ),
        }
        if "beta" in per_fold[0][name]:
            pooled["beta_per_fold"] = [r[name]["beta"] for r in per_fold]
        out[name] = pooled
    return out


def cv_table(cv: Mapping[str, Any]) -> str:
    """A Markdown table of :func:`cross_validate`'s pooled results."""
    lines = [
        f"{cv['folds']}-fold cross-validation by trajectory (held-out rows)",
        "",
        "| observer | accuracy (modal answer) | answer accuracy | NLL per answer (nats) | β |",
        "|---|---|---|---|---|",
    ]
    for name, r in cv.items():
        if not isinstance(r, dict) or "nll_per_answer" not in r:
            continue
        beta = r.get("beta_per_fold")
        b = "" if beta is None else f"{np.median(beta):.3g} (median of folds)"
        lines.append(
            f"| {name} | {r['accuracy']:.3f} | {r['answer_accuracy']:.3f} | "
            f"{r['nll_per_answer']:.4f} | {b} |"
        )
    for name, note in cv.get("notes", {}).items():
        lines.append(f"\n{name}: {note}")
    return "\n".join(lines)
