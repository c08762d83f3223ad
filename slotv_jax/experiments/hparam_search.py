"""Random hyperparameter search of the paper (SPEC §8), resumable.

Search spaces (paper preset):

- SLOT-V, phase ``slotv_large_batch``: lr ~ U[0.0004, 0.02], ρ ~ U[0.7, 0.999],
  momentum ~ U[0, 1], batch ∈ {64, 128, 256, 512}; 5 epochs. Phase
  ``slotv_small_batch``: the same with batch ∈ {8, 16, 32, 64}.
- T-REX, phase ``trex``: lr ~ U[1e-5, 1e-3], β1, β2 ~ U[0.7, 1), batch ∈ {64, 128, 256};
  15 epochs.
- Both: hidden layer 1 ∈ {1280, 1536, 1792}, layer 2 ∈ {256, 512, 768, 1024}, and
  in 20% of rollouts an extra hidden layer (its width drawn from the layer-2 set).

The score of a rollout is its accuracy (SPEC §8) on ``trajectory_val`` for the
chosen labeler (Dragan by default). The ``quick`` preset keeps the ranges of
the optimiser hyperparameters but divides the widths by 16, trains on the
first 4,000 trajectories for 1 (SLOT-V) or 3 (T-REX) epochs, and runs 8
rollouts per phase **[choice]**, so it finishes on a CPU in minutes.

Rollout ``i`` of a phase draws its hyperparameters from ``default_rng([seed,
phase, i])`` and trains with key ``i``, so every rollout is reproducible on its
own. Each finished rollout is appended atomically to ``OUT/rollouts.json``; a
rerun skips finished ones. ``OUT/summary.md`` ranks the rollouts and reports
which hyperparameters mattered (Spearman rank correlation with the score).

    python -m slotv_jax.experiments.hparam_search                    # quick, CPU
    python -m slotv_jax.experiments.hparam_search --preset paper --rollouts 25
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

import slotv_jax
from slotv_jax import config as train_config
from slotv_jax import data as data_lib
from slotv_jax.experiments import table1
from slotv_jax.experiments.table1 import LABELERS, dataset_dir
from slotv_jax.fileio import write_text

PHASES = {
    "slotv_large_batch": ("slotv", (64, 128, 256, 512)),
    "slotv_small_batch": ("slotv", (8, 16, 32, 64)),
    "trex": ("trex", (64, 128, 256)),
}
HIDDEN1 = (1280, 1536, 1792)
HIDDEN2 = (256, 512, 768, 1024)
EXTRA_LAYER_P = 0.2


@dataclasses.dataclass(frozen=True)
class SearchConfig:
    """Scale of the search."""

    preset: str = "quick"
    rollouts: int = 8  # per phase
    width_divisor: int = 16  # hidden widths are the paper's divided by this
    slotv_epochs: int = 1
    trex_epochs: int = 3
    train_size: int | None = 4000  # first n training trajectories (None: all)
    seed: int = 0

    def __post_init__(self):
        for f in ("rollouts", "width_divisor", "slotv_epochs", "trex_epochs"):
            if getattr(self, f) < 1:
                raise ValueError(f"SearchConfig.{f}: expected an integer >= 1")


def quick(**kw) -> SearchConfig:
    return SearchConfig(**{"preset": "quick", **kw})


def paper(**kw) -> SearchConfig:
    base = {"preset": "paper", "rollouts": 25, "width_divisor": 1, "slotv_epochs": 5}
    return SearchConfig(**{**base, "trex_epochs": 15, "train_size": None, **kw})


def tiny(**kw) -> SearchConfig:
    """Seconds-scale search for tests (not a result)."""
    base = {"preset": "tiny", "rollouts": 2, "width_divisor": 64, "train_size": None}
    return SearchConfig(**{**base, **kw})


PRESETS = {"quick": quick, "paper": paper, "tiny": tiny}


def sample_hparams(phase: str, i: int, cfg: SearchConfig) -> dict:
    """Hyperparameters of rollout ``i`` of ``phase`` (deterministic)."""
    method, batches = PHASES[phase]
    rng = np.random.default_rng([cfg.seed, list(PHASES).index(phase), i])
    hidden = [int(rng.choice(HIDDEN1)), int(rng.choice(HIDDEN2))]
    if rng.random() < EXTRA_LAYER_P:
        hidden.append(int(rng.choice(HIDDEN2)))
    hidden = [max(1, h // cfg.width_divisor) for h in hidden]
    hp: dict = {"hidden": hidden, "batch_size": int(rng.choice(batches))}
    if method == "slotv":
        hp["learning_rate"] = float(rng.uniform(0.0004, 0.02))
        hp["rho"] = float(rng.uniform(0.7, 0.999))
        hp["momentum"] = float(rng.uniform(0.0, 1.0))
        hp["epochs"] = cfg.slotv_epochs
    else:
        hp["learning_rate"] = float(rng.uniform(1e-5, 1e-3))
        hp["b1"] = float(rng.uniform(0.7, 1.0))
        hp["b2"] = float(rng.uniform(0.7, 1.0))
        hp["epochs"] = cfg.trex_epochs
    return hp


def spearman(x: np.ndarray, y: np.ndarray) -> float:
    """Spearman rank correlation (average ranks for ties); NaN if either is constant."""

    def rank(a):
        order = np.argsort(a, kind="stable")
        r = np.empty(len(a))
        r[order] = np.arange(len(a))
        for v in np.unique(a):  # average ties
            r[a == v] = r[a == v].mean()
        return r

    rx, ry = rank(np.asarray(x, float)), rank(np.asarray(y, float))
    if rx.std() == 0 or ry.std() == 0:
        return float("nan")
    return float(np.corrcoef(rx, ry)[0, 1])


def run(
    cfg: SearchConfig,
    out: Path,
    *,
    labeler: str = "dragan",
    phases: Sequence[str] = tuple(PHASES),
    cache: Path = Path("data"),
    progress: bool = True,
) -> dict:
    """Run (or resume) the search; returns the rollouts document."""
    from slotv_jax import evaluate, train

    out.mkdir(parents=True, exist_ok=True)
    path = out / "rollouts.json"
    doc = {"search": dataclasses.asdict(cfg), "labeler": labeler, "rollouts": []}
    if path.exists():
        old = json.loads(path.read_text())
        if (old.get("search"), old.get("labeler")) != (doc["search"], labeler):
            raise ValueError(f"{path}: results of another search config; use another --out")
        doc = old
    doc["environment"] = data_lib.environment()
    dcfg = table1.PRESETS[cfg.preset]().data
    dataset = data_lib.generate_dataset(
        dcfg, dataset_dir(cache, dcfg), splits=["train", "trajectory_val"], progress=progress
    )
    tdata = train.prepare(dataset["train"], labeler, size=cfg.train_size)
    done = {(r["phase"], r["index"]) for r in doc["rollouts"]}
    todo = [(p, i) for p in phases for i in range(cfg.rollouts) if (p, i) not in done]
    for phase, i in tqdm(todo, desc="rollouts", unit="rollout", disable=not progress):
        method = PHASES[phase][0]
        hp = sample_hparams(phase, i, cfg)
        tc = train_config.preset("paper", method, **{**hp, "hidden": tuple(hp["hidden"])})
        t0 = time.perf_counter()
        state, metrics = train.train_trials(tc, tdata, [i], progress=False)
        acc = evaluate.accuracy(tc, state.params, dataset["trajectory_val"], labeler)
        loss = np.asarray(metrics.loss)[0]
        doc["rollouts"].append(
            {
                "phase": phase,
                "index": i,
                "method": method,
                "hparams": hp,
                "val_accuracy": float(np.asarray(acc).reshape(-1)[0]),
                "final_loss": float(loss[-1].mean()),
                "finite": bool(np.all(np.isfinite(loss))),
                "time_s": time.perf_counter() - t0,
            }
        )
        write_text(path, json.dumps(doc, indent=1))
    summary = summarise(doc)
    write_text(out / "summary.md", summary)
    return doc


def summarise(doc: dict) -> str:
    """Markdown: best rollouts per phase and the rank correlation of each hyperparameter."""
    lines = [
        f"# Hyperparameter search ({doc['search']['preset']} preset, labeler {doc['labeler']})",
        "",
        "Score: accuracy on trajectory_val. ρ: Spearman rank correlation of the "
        "hyperparameter with the score over the phase's rollouts (|ρ| near 1: it mattered).",
    ]
    for phase in PHASES:
        rs = [r for r in doc["rollouts"] if r["phase"] == phase]
        if not rs:
            continue
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
        for k, c in sorted(corr.items(), key=lambda kv: -abs(np.nan_to_num(kv[1]))):
            lines.append(f"| {k} | {c:+.2f} |")
        lines += ["", "| rank | score | hyperparameters |", "|---|---|---|"]
        for n, j in enumerate(np.argsort(-score)[:5]):
            lines.append(f"| {n + 1} | {score[j]:.3f} | `{json.dumps(rs[j]['hparams'])}` |")
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m slotv_jax.experiments.hparam_search",
        description="The SLOT-V paper's random hyperparameter search.",
    )
    p.add_argument("--preset", choices=sorted(PRESETS), default="quick")
    p.add_argument("--rollouts", type=int, help="rollouts per phase (default: the preset's)")
    p.add_argument("--labeler", choices=LABELERS, default="dragan")
    p.add_argument("--phases", nargs="+", choices=list(PHASES), default=list(PHASES))
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=Path, help="default: runs/hparam_search_<preset>")
    p.add_argument("--cache", type=Path, default=Path("data"))
    args = p.parse_args(argv)
    print(slotv_jax.XLA_CONFIG.summary(), file=sys.stderr)
    kw = {"seed": args.seed}
    if args.rollouts is not None:
        kw["rollouts"] = args.rollouts
    cfg = PRESETS[args.preset](**kw)
    out = args.out or Path("runs") / f"hparam_search_{args.preset}"
    run(cfg, out, labeler=args.labeler, phases=args.phases, cache=args.cache)
    print((out / "summary.md").read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
