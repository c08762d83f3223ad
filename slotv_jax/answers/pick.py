"""The researcher's pick on a study file: ``python -m slotv_jax.study pick``.

Every candidate observer (the families of :data:`slotv_jax.training.config.FAMILIES` and
the hand-crafted labelers with a fitted β) is scored by the held-out likelihood of the
study's answers: K folds by motion, each candidate fitted on the other folds and
predicting the held-out one (:func:`out_of_fold`). The log-linear pool of the candidates
(:mod:`slotv_jax.answers.pooling`) weighs them by those predictions; the candidate of the
largest weight is the pick. The same procedure, on simulated answers, is the people loop's
family ``pick``. Only the study's answers are read.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
import numpy as np
from jaxtyping import Float
from tqdm.auto import tqdm

from slotv_jax.answers import pooling
from slotv_jax.answers.crossval import fit_beta, labeler_probs, labeler_visible
from slotv_jax.answers.fitting import answer_logits, train_study
from slotv_jax.answers.format import PROB_FLOOR, Study
from slotv_jax.training import config as train_config

LABELERS = ("dragan", "nikolaidis")  # the hand-crafted candidates (β fitted)
CANDIDATES = (*train_config.FAMILIES, *LABELERS)


def check_candidates(names: Sequence[str]) -> tuple[str, ...]:
    """Distinct names of :data:`CANDIDATES`, at least two (ValueError naming the flag)."""
    names = tuple(names)
    bad = [n for n in names if n not in CANDIDATES]
    if bad or len(set(names)) < len(names) or len(names) < 2:
        raise ValueError(
            f"--candidates: expected at least two distinct names of {list(CANDIDATES)}, "
            f"got {list(names)}"
        )
    return names


def _log_probs(logits: np.ndarray, mask: np.ndarray) -> np.ndarray:
    z = np.where(mask, logits, -np.inf)
    z = z - z.max(-1, keepdims=True)
    return np.where(mask, z - np.log(np.exp(z).sum(-1, keepdims=True)), -np.inf)


def out_of_fold(
    study: Study,
    names: Sequence[str],
    *,
    preset: str = "quick",
    folds: int = 3,
    seed: int = 0,
    camera: str = "observer",
    progress: bool = True,
) -> tuple[Float[np.ndarray, "F A G"], np.ndarray]:
    """Each candidate's log-probabilities of every answer row, predicted by its fit on the
    other folds (folds by motion, :func:`slotv_jax.answers.pooling.fold_of`); and the rows'
    folds. Learned families train with ``preset``'s config; labelers get β by
    :func:`slotv_jax.answers.crossval.fit_beta`."""
    names = check_candidates(names)
    fold = pooling.fold_of(study.answer_trajectory, folds, seed)
    g = study.counts.shape[-1]
    mask = study.goal_mask[study.answer_trajectory, :g]
    out = np.full((len(names), study.n_rows, g), -np.inf, np.float32)
    bar = tqdm(total=folds * len(names), desc="held-out fits", disable=not progress)
    for f in range(folds):
        rows = np.flatnonzero(fold == f)
        tr, te = study.select_rows(fold != f), study.select_rows(fold == f)
        for j, name in enumerate(names):
            if name in LABELERS:
                beta, _ = fit_beta(tr, name, camera=camera)
                y = labeler_probs(te, name, beta=beta, camera=camera)[:, :g]
                with np.errstate(divide="ignore"):
                    lp = np.where(mask[rows], np.log(np.maximum(y, PROB_FLOOR)), -np.inf)
            else:
                cfg = fit_config(preset, name, tr.n_rows)
                state = train_study(cfg, tr, jax.random.key(seed * 1000 + f), progress=False)
                z = np.full((rows.size, g), -np.inf, np.float32)
                lg = answer_logits(cfg, state.params, te)  # the study's goal slots in use
                z[:, : lg.shape[-1]] = lg[:, :g]
                lp = _log_probs(z, mask[rows])
            out[j, rows] = lp
            bar.update(1)
    bar.close()
    return out, fold


def fit_config(preset: str, name: str, rows: int) -> train_config.TrainConfig:
    """The family's config, with a batch that fits a small study (as ``study train``)."""
    cfg = train_config.family(preset, name)
    if rows < cfg.batch_size:
        cfg = train_config.apply_overrides(cfg, [f"batch_size={1 << (rows.bit_length() - 1)}"])
    return cfg


def pick_study(
    study: Study,
    names: Sequence[str] = CANDIDATES,
    *,
    preset: str = "quick",
    folds: int = 3,
    seed: int = 0,
    camera: str = "observer",
    progress: bool = True,
) -> dict:
    """The pick of ``study``: :func:`out_of_fold` then
    :func:`slotv_jax.answers.pooling.pick_report` (each candidate's held-out NLL per answer,
    the pool's weights and NLL, ``pick`` the candidate of the largest weight)."""
    names = check_candidates(names)
    if not (isinstance(folds, int) and 2 <= folds <= study.n_trajectories):
        raise ValueError(
            f"--folds: expected 2 <= folds <= {study.n_trajectories} (motions), got {folds!r}"
        )
    if "nikolaidis" in names and not labeler_visible(study, camera):
        raise ValueError(
            f"--candidates: nikolaidis needs every point and goal in front of camera {camera!r}"
        )
    logp, _ = out_of_fold(
        study, names, preset=preset, folds=folds, seed=seed, camera=camera, progress=progress
    )
    g = study.counts.shape[-1]
    mask = study.goal_mask[study.answer_trajectory, :g]
    rep = pooling.pick_report(list(names), logp, study.counts[:, :g], mask)
    return {**rep, "folds": folds, "seed": seed, "preset": preset}


def pick_table(rep: dict) -> str:
    """A Markdown table of :func:`pick_study`'s report."""
    lines = [
        f"{rep['folds']}-fold held-out likelihood by motion; the pool's weights "
        "(log-linear, fitted on the held-out predictions)",
        "",
        "| candidate | held-out NLL per answer (nats) | weight |",
        "|---|---|---|",
    ]
    for n, nll, w in zip(rep["candidates"], rep["heldout_nll"], rep["weights"], strict=True):
        mark = " **(pick)**" if n == rep["pick"] else ""
        lines.append(f"| {n}{mark} | {nll:.4f} | {w:.3f} |")
    lines.append(f"| pool | {rep['pool_nll']:.4f} | |")
    return "\n".join(lines)
