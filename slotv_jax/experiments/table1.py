"""Table 1 of the paper: accuracy of SLOT-V and T-REX on every labeler and split
(:ref:`concepts-accuracy`).

    python -m slotv_jax.experiments.table1                      # quick preset, CPU, minutes
    python -m slotv_jax.experiments.table1 --preset paper       # paper sizes (GPU)
    python -m slotv_jax.experiments.table1 --labelers dragan --methods slotv --trials 3

Steps: generate (or reuse) the seven dataset splits, cached by config digest;
train each (labeler, method, trial) cell; evaluate it on the four Table 1
splits; write the cell to ``OUT/results.json`` atomically as soon as it
finishes. A rerun with the same ``--out`` skips finished cells, so an
interrupted run loses at most the cell in flight. The end of the run prints
the table in the paper's layout (mean ± SD over trials, the paper's values and
the difference) and writes ``OUT/table1.md``.

On several devices (and hosts, with ``--coordinator``/``--num-processes``/
``--process-id`` or ``--distributed``) the pending trials of each method, all
labelers together, train side by side, one per device
(:mod:`slotv_jax.training.parallel`); each group is written as it finishes.
``--time-limit SECONDS`` stops before a group that would end later; the same
command resumes.
"""

from __future__ import annotations

import dataclasses
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

import slotv_jax
from slotv_jax import data as data_lib
from slotv_jax.core import cli, distributed, fileio
from slotv_jax.core.defaults import LABELER_NAMES, TEST_SPLITS
from slotv_jax.core.fileio import write_text
from slotv_jax.runs import grid
from slotv_jax.runs.grid import merge
from slotv_jax.runs.paper import PAPER_TABLE
from slotv_jax.runs.presets import (
    LABELER_TITLES,
    METHODS,
    PRESETS,
    SPLIT_TITLES,
    RunConfig,
    with_compute_dtype,
    with_model,
)
from slotv_jax.training import config as train_config


def render_table(summary: list[dict]) -> str:
    """Markdown table in the paper's layout: ours ± SD, the paper's, and the difference."""
    by = {(s["labeler"], s["method"], s["split"]): s for s in summary}
    lines = [
        "| labeler | split | SLOT-V (ours) | SLOT-V (paper) | Δ "
        "| T-REX (ours) | T-REX (paper) | Δ |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for lab in LABELER_NAMES:
        for i, split in enumerate(TEST_SPLITS):
            row = [LABELER_TITLES[lab] if i == 0 else "", SPLIT_TITLES[split]]
            for meth in METHODS:
                s = by.get((lab, meth, split))
                pm, psd = PAPER_TABLE[(lab, meth, split)]
                if s is None:
                    row += ["—", f"{pm:.3f} ({psd:.3f})", "—"]
                else:
                    ours = f"{s['mean']:.3f} ± {s['sd']:.3f} (n={s['n']})"
                    row += [ours, f"{pm:.3f} ({psd:.3f})", f"{s['mean'] - pm:+.3f}"]
            lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines)


#: What good looks like on the quick preset: its networks (64, 32), trained for 3 epochs of
#: 8,000 trajectories (2 trials), sit below the paper's. The record
#: (experiments/table1_quick.md): SLOT-V's Δ from −0.193 to −0.012 in every cell, T-REX's
#: from −0.185 to +0.073 (EffDist above the paper), SLOT-V above T-REX in all 16 pairs.
QUICK_GOOD = (
    "SLOT-V 0.01-0.19 below the paper in every cell, T-REX from 0.19 below to 0.07 above, "
    "SLOT-V above T-REX in every (labeler, split) pair"
)


def expectation(doc: dict) -> str | None:
    """The line the main job prints under the quick preset's table: what good looks like
    (:data:`QUICK_GOOD`, the record's) and this run's own ranges of Δ and count of pairs
    where SLOT-V is above T-REX; ``None`` for another preset or an archetype's run."""
    model = doc["config"].get("train", {}).get("slotv", {}).get("model", "mlp")
    if doc["preset"] != "quick" or model != "mlp" or not doc["summary"]:
        return None
    by = {(s["labeler"], s["method"], s["split"]): s["mean"] for s in doc["summary"]}
    runs = []
    for meth, title in zip(METHODS, ("SLOT-V", "T-REX"), strict=True):
        delta = [m - PAPER_TABLE[k][0] for k, m in by.items() if k[1] == meth]
        if delta:
            runs.append(f"{title} Δ {min(delta):+.3f} to {max(delta):+.3f}")
    pairs = [(lab, split) for lab, meth, split in by if meth == "slotv"
             and (lab, "trex", split) in by]  # fmt: skip
    if pairs:
        above = sum(by[(lab, "slotv", sp)] > by[(lab, "trex", sp)] for lab, sp in pairs)
        runs.append(f"SLOT-V above T-REX in {above} of {len(pairs)} pairs")
    return (
        f"what good looks like on the quick preset (small networks trained briefly; "
        f"experiments/table1_quick.md): {QUICK_GOOD}; this run: {', '.join(runs)}; the "
        "paper's values need --preset paper"
    )


def run(cfg: RunConfig, out: Path, **kw) -> dict:
    """Run (or resume) Table 1: the grid of trained cells of ``cfg`` (:func:`slotv_jax.runs.
    grid.run`, which takes the keywords ``kw``), then ``OUT/table1.md`` rendered from the
    results document. Returns the document."""
    doc = grid.run(cfg, out, **kw)
    if distributed.is_writer():
        write_text(out / "table1.md", report(doc))
    return doc


def report(doc: dict) -> str:
    """The Markdown report: how it was made and the table."""
    env = doc["environment"]
    cells = doc["timing"]["cells"]
    per_cell = np.mean([c["total_s"] for c in cells]) if cells else float("nan")
    model = doc["config"].get("train", {}).get("slotv", {}).get("model", "mlp")
    note = (
        []
        if model == "mlp"
        else [
            f"The SLOT-V columns are the `{model}` observer archetype "
            "(slotv_jax.observers.parametric), trained with SLOT-V's loss; the paper's SLOT-V "
            "is its network. T-REX is the MLP.",
            "",
        ]
    )
    return "\n".join(
        [
            f"# Table 1 ({doc['preset']} preset)",
            "",
            *note,
            "Accuracy (concepts: metrics) as mean ± SD over trials; the paper's values "
            f"(10 trials) "
            f"in parentheses. {len(doc['cells']) // len(TEST_SPLITS)} trained models, "
            f"{per_cell:.1f} s per cell on average (training and evaluation).",
            "",
            f"jax {env.get('jax')}, flax {env.get('flax')}, mujoco {env.get('mujoco')}, "
            f"devices {env.get('devices')}.",
            "",
            render_table(doc["summary"]),
            "",
        ]
    )


@cli.command(resumes=True)
def main(argv: Sequence[str] | None = None) -> int:
    p = cli.ArgumentParser(
        prog="python -m slotv_jax.experiments.table1",
        description="Reproduce Table 1 of the SLOT-V paper.",
    )
    p.add_argument("--preset", choices=sorted(PRESETS), default="quick")
    p.add_argument("--labelers", nargs="+", choices=LABELER_NAMES, default=list(LABELER_NAMES))
    p.add_argument("--methods", nargs="+", choices=METHODS, default=list(METHODS))
    p.add_argument("--trials", type=int, help="trials per cell (default: the preset's)")
    p.add_argument("--out", type=Path, help="results directory (default: runs/table1_<preset>)")
    p.add_argument(
        "--cache",
        type=Path,
        default=data_lib.DEFAULT_CACHE,
        help="dataset cache directory (default: data; other commands find the default "
        "dataset there by the preset's name, --data quick)",
    )
    p.add_argument(
        "--distribution",
        choices=sorted(data_lib.DATA_DISTRIBUTIONS),
        default="default",
        help="dataset distribution: trajectories and label temperatures (default: chosen by "
        "the fidelity ablation; spec_v1: the first version's 3-5 via points and β)",
    )
    p.add_argument(
        "--compute-dtype",
        choices=("float32", "bfloat16"),
        help="matmul dtype of the hidden layers (default: the preset's, float32)",
    )
    p.add_argument(
        "--model",
        choices=train_config.MODELS,
        default="mlp",
        help="observer trained with SLOT-V's loss: the paper's network (mlp, default) or a "
        "parametric archetype (concepts: archetypes); T-REX keeps its network",
    )
    p.add_argument(
        "--vmap-trials",
        action="store_true",
        help="train the trials of each (labeler, method) together in one vmapped call",
    )
    p.add_argument(
        "--merge",
        nargs="+",
        type=Path,
        metavar="DIR",
        help="only merge the results.json of these run directories (same configuration, "
        "e.g. one per GPU) into --out, and render the table",
    )
    p.add_argument(
        "--time-limit",
        type=float,
        metavar="SECONDS",
        help="stop before a trial (group) that would end after this many seconds; "
        "rerun the same command to continue",
    )
    distributed.add_cli_args(p)
    args = p.parse_args(argv)
    suffix = "" if args.model == "mlp" else f"_{args.model}"
    out = args.out or Path("runs") / f"table1_{args.preset}{suffix}"
    if args.merge and args.out is None:
        raise cli.InputError("--merge needs --out")
    # a results directory of ours is resumed (finished cells are kept); else refused
    fileio.check_output_dir(out, ours=fileio.is_results_dir, resume=True)
    distributed.init_from_args(args)
    print(slotv_jax.XLA_CONFIG.summary(), file=sys.stderr)
    if args.merge:
        try:
            doc = merge([fileio.read_json(d / "results.json") for d in args.merge])
        except KeyError as e:
            raise cli.InputError(f"--merge: a results.json lacks the field {e}") from None
        args.out.mkdir(parents=True, exist_ok=True)
        write_text(args.out / "results.json", json.dumps(doc, indent=1))
        write_text(args.out / "table1.md", report(doc))
        print(render_table(doc["summary"]))
        return 0

    cfg = PRESETS[args.preset]()
    if args.trials is not None:
        if args.trials < 1:
            p.error("--trials: expected an integer >= 1")
        cfg = dataclasses.replace(cfg, trials=args.trials)
    if args.compute_dtype is not None:
        cfg = with_compute_dtype(cfg, args.compute_dtype)
    if args.distribution != "default":
        cfg = dataclasses.replace(cfg, data=data_lib.with_distribution(cfg.data, args.distribution))
    if args.time_limit is not None and not args.time_limit >= 0:
        p.error("--time-limit: expected a number of seconds >= 0")
    cfg = with_model(cfg, args.model)
    t0 = time.perf_counter()
    doc = run(
        cfg,
        out,
        labelers=args.labelers,
        methods=args.methods,
        cache=args.cache,
        vmap_trials=args.vmap_trials,
        time_limit_s=args.time_limit,
    )
    if not distributed.is_writer():
        return 0
    print()
    print(render_table(doc["summary"]))
    if (good := expectation(doc)) is not None:
        print(good)
    print(
        f"\n{len(doc['cells'])} cell results in {out / 'results.json'}; table in "
        f"{out / 'table1.md'}; this run took {time.perf_counter() - t0:.0f} s"
    )
    ddir = data_lib.dataset_dir(args.cache, cfg.data)
    found = args.preset in data_lib.PRESETS and ddir == data_lib.preset_dir(args.preset)
    print(f"dataset in {ddir}" + (f" (other commands: --data {args.preset})" if found else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
