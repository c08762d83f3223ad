"""The hyperparameter search's summary, rendered from its rollouts document alone
(``OUT/rollouts.json`` of :mod:`slotv_jax.experiments.hparam_search`): how it was run, the
best rollouts of each phase (in the order the search ran them), the rank correlation of
each hyperparameter with the score, and the paper's choices beside the best rollouts.
"""

from __future__ import annotations

import json

import numpy as np

from slotv_jax.runs.summary import spearman
from slotv_jax.training import config as train_config


def _header(doc: dict) -> list[str]:
    """How the results were made: commands, machine, versions, dates, wall time."""
    env = doc.get("environment", {})
    runs = doc.get("invocations", [])
    lines = []
    if runs:
        wall = sum(r["wall_s"] for r in runs)
        lines += [
            f"- Commands ({len(runs)} invocation(s), each resuming the last; "
            f"**wall time {wall:.0f} s** in all, dataset generation or loading included):",
            "",
            *[
                f"  - `{r['command'] or '(library call)'}`: {r['date']}, {r['wall_s']:.0f} s "
                f"({r['rollouts_run']} rollouts run, {r['rollouts_left']} left), "
                f"{r['processes']} process(es), devices {', '.join(r['devices'])} "
                f"({r.get('device_kind', '?')})"
                for r in runs
            ],
            "",
        ]
    lines += [
        f"- Versions: slotv_jax {env.get('slotv_jax')}, jax {env.get('jax')}, "
        f"flax {env.get('flax')}, optax {env.get('optax')}, mujoco {env.get('mujoco')}, "
        f"numpy {env.get('numpy')}, Python {env.get('python')}.",
        f"- Search: {json.dumps(doc['search'])}.",
    ]
    return lines


def _against_paper(doc: dict) -> list[str]:
    """The best rollouts set against the hyperparameters the paper settled on
    (:ref:`concepts-slotv`, :ref:`concepts-trex`, :ref:`concepts-datasets`,
    :ref:`concepts-hparam-search`)."""
    lines = ["", "## Against the paper's account", ""]
    lines += [
        "The paper searched SLOT-V first with batches of 64–512, then ran 25 more rollouts "
        "with batches of 8–64, and settled on RMSprop lr 0.005, ρ 0.9, momentum 0, batch 32, "
        "hidden 1536/768; for T-REX on Adam lr 0.005, β1 0.9, β2 0.999, batch 128, hidden "
        "1792/768 (concepts: SLOT-V, T-REX, metrics). Its T-REX lr of 0.005 lies outside its "
        "own T-REX search range, U[1e-5, 1e-3].",
        "",
        "| phase | n | best | median | paper's choice | best rollout here |",
        "|---|---|---|---|---|---|",
    ]
    paper = {
        "slotv": train_config.paper("slotv"),
        "trex": train_config.paper("trex"),
    }
    best = {}
    for phase in dict.fromkeys(r["phase"] for r in doc["rollouts"]):
        rs = [r for r in doc["rollouts"] if r["phase"] == phase]
        method = rs[0]["method"]
        score = np.array([r["val_accuracy"] for r in rs])
        b = rs[int(np.argmax(score))]
        best[phase] = (score.max(), np.median(score))
        pc = paper[method]
        keys = (
            ("learning_rate", "rho", "momentum")
            if method == "slotv"
            else ("learning_rate", "b1", "b2")
        )
        mine = ", ".join(f"{k} {b['hparams'][k]:.3g}" for k in keys)
        ours = f"{mine}, batch {b['hparams']['batch_size']}, hidden {b['hparams']['hidden']}"
        theirs = ", ".join(f"{k} {getattr(pc, k):g}" for k in keys)
        theirs += f", batch {pc.batch_size}, hidden {list(pc.hidden)}"
        lines.append(
            f"| {phase} | {len(rs)} | {score.max():.3f} | {np.median(score):.3f} | {theirs} "
            f"| {ours} |"
        )
    if "slotv_large_batch" in best and "slotv_small_batch" in best:
        (bl, ml), (bs, ms) = best["slotv_large_batch"], best["slotv_small_batch"]
        better = "higher" if bs > bl else "not higher"
        lines += [
            "",
            f"The small-batch phase scored {better} than the large-batch phase here (best "
            f"{bs:.3f} vs {bl:.3f}, median {ms:.3f} vs {ml:.3f}); the paper's move to small "
            "batches, and its final batch of 32, suggest it found the same direction."
            if bs > bl
            else f"The small-batch phase did not score higher than the large-batch phase here "
            f"(best {bs:.3f} vs {bl:.3f}, median {ms:.3f} vs {ml:.3f}), unlike what the "
            "paper's move to small batches suggests.",
        ]
    return lines


def summarise(doc: dict) -> str:
    """Markdown: how it was run, best rollouts per phase, the rank correlation of each
    hyperparameter with the score, which of them mattered, and the paper's choices beside
    the best rollouts."""
    lines = [
        f"# Hyperparameter search ({doc['search']['preset']} preset, labeler {doc['labeler']})",
        "",
        *_header(doc),
        "",
        "Score: accuracy on trajectory_val. ρ: Spearman rank correlation of the "
        "hyperparameter with the score over the phase's rollouts (|ρ| near 1: it mattered; "
        "|ρ| ≥ 1.96/√(n−1), 0.40 for n = 25, is significant at about p < 0.05).",
    ]
    for phase in dict.fromkeys(r["phase"] for r in doc["rollouts"]):
        rs = [r for r in doc["rollouts"] if r["phase"] == phase]
        score = np.array([r["val_accuracy"] for r in rs])
        lines += ["", f"## {phase} ({len(rs)} rollouts)", ""]
        lines += [f"Score: best {score.max():.3f}, median {np.median(score):.3f}, "
                  f"worst {score.min():.3f}.", ""]  # fmt: skip
        feats = {
            "learning_rate": [r["hparams"]["learning_rate"] for r in rs],
            "batch_size": [r["hparams"]["batch_size"] for r in rs],
            "hidden_1": [r["hparams"]["hidden"][0] for r in rs],
            "hidden_2": [r["hparams"]["hidden"][1] for r in rs],
            "extra_layer": [len(r["hparams"]["hidden"]) > 2 for r in rs],
        }
        for k in ("rho", "momentum", "b1", "b2"):
            if k in rs[0]["hparams"]:
                feats[k] = [r["hparams"][k] for r in rs]
        lines += ["| hyperparameter | ρ with score |", "|---|---|"]
        corr = {k: spearman(np.asarray(v, float), score) for k, v in feats.items()}
        ranked = sorted(corr.items(), key=lambda kv: -abs(np.nan_to_num(kv[1])))
        for k, c in ranked:
            lines.append(f"| {k} | {c:+.2f} |")
        crit = 1.96 / np.sqrt(max(len(rs) - 1, 1))
        mattered = [f"{k} ({c:+.2f})" for k, c in ranked if abs(np.nan_to_num(c)) >= crit]
        lines += ["", f"Mattered (|ρ| ≥ {crit:.2f}): {', '.join(mattered) or 'none'}."]
        lines += ["", "| rank | score | hyperparameters |", "|---|---|---|"]
        for n, j in enumerate(np.argsort(-score)[:5]):
            lines.append(f"| {n + 1} | {score[j]:.3f} | `{json.dumps(rs[j]['hparams'])}` |")
    lines += _against_paper(doc)
    return "\n".join(lines) + "\n"
