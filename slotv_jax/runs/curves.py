"""Sample-efficiency learning curves (:ref:`concepts-sample-efficiency`, the paper's Fig. 3): each
method trains one epoch with in-loop validation every few updates, repeated over seeds; the examples
each needs to reach a threshold; the CSV, JSON and figure of a run.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import json
import time
from collections.abc import Sequence
from pathlib import Path

import jax
import numpy as np

from slotv_jax.core import distributed
from slotv_jax.core.environment import environment
from slotv_jax.core.fileio import write_text
from slotv_jax.data.generate import cached_dataset
from slotv_jax.runs import figures, presets
from slotv_jax.runs.presets import METHOD_TITLES, METHODS
from slotv_jax.runs.summary import examples_to_reach
from slotv_jax.training import evaluate, parallel, schedule, types
from slotv_jax.training import trainer as train

LABELER = "dragan"


def run(
    preset: str,
    out: Path,
    *,
    repeats: int,
    every: int = 10,
    val_size: int = 1000,
    threshold: float = 0.8,
    methods: Sequence[str] = METHODS,
    cache: Path = Path("data"),
    progress: bool = True,
    compute_dtype: str | None = None,
    model: str = "mlp",
    labeler: str = LABELER,
) -> dict:
    """Run the protocol for each method and write the CSV, JSON and PNG.

    ``model`` replaces SLOT-V's network by an observer archetype (:ref:`concepts-archetypes`,
    :func:`slotv_jax.experiments.presets.with_model`); ``labeler`` trains and validates on
    another labeler's labels than the paper's Dragan."""

    if preset not in presets.PRESETS:
        raise ValueError(f"preset: expected one of {sorted(presets.PRESETS)}, got {preset!r}")
    t1 = presets.PRESETS[preset]()
    if compute_dtype is not None:
        t1 = presets.with_compute_dtype(t1, compute_dtype)
    t1 = presets.with_model(t1, model)
    dcfg = t1.data
    if distributed.is_writer():
        out.mkdir(parents=True, exist_ok=True)
    dataset = cached_dataset(dcfg, cache, splits=["train", "trajectory_val"], progress=progress)
    tdata = types.prepare(dataset["train"], labeler)
    vdata = types.prepare(dataset["trajectory_val"], labeler)
    val_size = min(val_size, len(dataset["trajectory_val"]))
    rows: list[dict] = []
    summary: dict[str, dict] = {}
    configs = {}
    for method in methods:
        base = t1.train[method]
        cfg = dataclasses.replace(
            base, epochs=1, train_size=None, eval_every=every, eval_size=val_size
        )
        configs[method] = cfg.to_dict()
        t0 = time.perf_counter()
        metrics = train_repeats(cfg, tdata, vdata, repeats, progress=progress)
        elapsed = time.perf_counter() - t0
        upd = np.concatenate([[0], metrics.eval_updates[0, 0]])
        acc = np.concatenate(
            [metrics.start_accuracy[:, None], metrics.eval_accuracy[:, 0]], axis=1
        )  # (repeats, V + 1)
        # The exact fractions correct / val_size: the float32 ratio's last bit depends on
        # how XLA compiled the division (one device or several).
        acc = evaluate.exact_fraction(acc, val_size)
        examples = upd * cfg.batch_size
        for r in range(repeats):
            for u, x, a in zip(upd, examples, acc[r], strict=True):
                rows.append(
                    {
                        "method": method,
                        "repeat": r,
                        "updates": int(u),
                        "examples": int(x),
                        "accuracy": float(a),
                    }
                )
        mean = acc.mean(0)
        per_repeat = [examples_to_reach(examples, acc[r], threshold) for r in range(repeats)]
        summary[method] = {
            "examples_to_threshold_mean_curve": examples_to_reach(examples, mean, threshold),
            "examples_to_threshold_per_repeat": per_repeat,
            "final_accuracy_mean": float(mean[-1]),
            "final_accuracy_sd": float(acc[:, -1].std(ddof=1)) if repeats > 1 else 0.0,
            "examples_per_epoch": int(examples[-1]),
            "time_s": elapsed,
        }
    doc = {
        "preset": preset,
        "labeler": labeler,
        "model": model,
        "protocol": {
            "epochs": 1,
            "evaluate_every_updates": every,
            "validation": f"first {val_size} trajectories of trajectory_val",
            "x_axis": "training examples consumed: trajectories (SLOT-V), pairs (T-REX)",
            "repeats": repeats,
            "threshold": threshold,
            "train_trajectories": len(dataset["train"]),
        },
        "config": configs,
        "summary": summary,
        "environment": environment(),
    }
    if distributed.is_writer():
        write_text(out / "sample_efficiency.csv", _csv(rows))
        write_text(out / "sample_efficiency.json", json.dumps(doc, indent=1))
        plot(rows, summary, doc, out / "sample_efficiency.png")
    return doc


def train_repeats(cfg, tdata, vdata, repeats: int, *, progress: bool = True):
    """The metrics (as NumPy, leading axis: repeat r, trained with seed r) of ``repeats``
    runs with in-loop validation, all in one vmapped call: on one device
    :func:`slotv_jax.training.trainer.train_trials`; on several (every process's) the repeat axis,
    padded to a multiple of the device count, sharded over them
    (:func:`slotv_jax.training.parallel.train_group`; the repeats share every shape, and vmapping
    them keeps the small in-loop validations batched, as on one device)."""

    n_dev = jax.device_count()
    if n_dev == 1:
        _, m = train.train_trials(cfg, tdata, list(range(repeats)), val=vdata, progress=progress)
        return jax.tree.map(np.asarray, m)
    mesh = schedule.unit_mesh(n_dev, cfg.batch_size)
    show = progress and jax.process_count() == 1
    _, m = parallel.train_group(cfg, tdata, range(repeats), mesh, val=vdata, progress=show)
    return jax.tree.map(lambda x: distributed.fetch(x)[:repeats], m)


def _csv(rows: list[dict]) -> str:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=["method", "repeat", "updates", "examples", "accuracy"])
    w.writeheader()
    w.writerows(rows)
    return buf.getvalue()


def curve(rows: list[dict], method: str) -> tuple[np.ndarray, np.ndarray]:
    """Examples (V,) and accuracy (repeats, V) of ``method``'s curves in the rows of a run
    (:func:`read_rows`)."""
    r = [row for row in rows if row["method"] == method]
    x = np.array(sorted({row["examples"] for row in r}))
    acc = np.array(
        [
            [row["accuracy"] for row in r if row["repeat"] == k]
            for k in sorted({row["repeat"] for row in r})
        ]
    )
    return x, acc


def read_rows(out: Path) -> list[dict]:
    """The rows of ``OUT/sample_efficiency.csv`` (method, repeat, updates, examples,
    accuracy), typed."""
    with open(Path(out) / "sample_efficiency.csv", newline="") as f:
        return [
            {**r, "repeat": int(r["repeat"]), "updates": int(r["updates"]),
             "examples": int(r["examples"]), "accuracy": float(r["accuracy"])}
            for r in csv.DictReader(f)
        ]  # fmt: skip


def plot(rows: list[dict], summary: dict, doc: dict, path: Path) -> None:
    """Mean ± SD validation accuracy against examples seen, both methods on one axis."""
    plt = figures.pyplot()
    fig, ax = plt.subplots(figsize=(7, 4.2), dpi=150)
    for method, color in zip(summary, ("tab:blue", "tab:orange"), strict=False):
        x, acc = curve(rows, method)
        title = METHOD_TITLES[method]
        if method == "slotv" and doc.get("model", "mlp") != "mlp":
            title = f"{doc['model']} archetype"
        figures.band(ax, x, *figures.mean_sd(acc, ddof=1), color=color, alpha=0.25,
                     label=f"{title} (n={len(acc)})")  # fmt: skip
        hit = summary[method]["examples_to_threshold_mean_curve"]
        if hit is not None:
            ax.axvline(hit, color=color, linestyle=":", linewidth=1)
    thr = doc["protocol"]["threshold"]
    ax.axhline(thr, color="grey", linestyle="--", linewidth=0.8)
    first = min(row["examples"] for row in rows if row["examples"])
    ax.set_xscale("symlog", linthresh=max(1, first))
    ax.set_xlim(0, max(row["examples"] for row in rows) * 1.05)
    ax.set_xlabel("training examples seen (SLOT-V: trajectories, T-REX: pairs)")
    ax.set_ylabel("validation accuracy (trajectory_val)")
    ax.set_ylim(0, 1)
    lab = doc.get("labeler", LABELER).capitalize()
    ax.set_title(f"Sample efficiency on {lab} labels ({doc['preset']} preset, one epoch)")
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right")
    fig.tight_layout()
    figures.save(fig, path)


def replot(out: Path) -> None:
    """Render ``OUT/sample_efficiency.png`` again from the saved CSV and JSON."""
    doc = json.loads((out / "sample_efficiency.json").read_text())
    plot(read_rows(out), doc["summary"], doc, out / "sample_efficiency.png")
