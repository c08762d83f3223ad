"""Sample efficiency of SLOT-V and T-REX: the paper's Fig. 3 (:ref:`concepts-sample-efficiency`).

Protocol: each method trains on Dragan labels for one epoch of the train split;
every ``--every`` updates (10 in the paper) the model is evaluated on a fixed
subset of ``trajectory_val`` (the first ``--val-size`` trajectories). The
x axis is the number of training examples consumed so far: labelled
trajectories for SLOT-V, labelled trajectory pairs for T-REX (its training
examples; an epoch has as many pairs as there are training trajectories,
:ref:`concepts-trex`). Each method is repeated ``--repeats`` times with different seeds;
the plot shows the mean ± SD over repeats.

    python -m slotv_jax.experiments.sample_efficiency                 # quick (CPU)
    python -m slotv_jax.experiments.sample_efficiency --preset paper  # paper networks (GPU)

Writes ``OUT/sample_efficiency.csv`` (method, repeat, updates, examples,
accuracy), ``OUT/sample_efficiency.json`` (protocol, config, the examples each
method needs to reach the threshold) and ``OUT/sample_efficiency.png``.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Sequence
from pathlib import Path

import slotv_jax
from slotv_jax.core import cli, distributed, fileio
from slotv_jax.runs.curves import replot, run
from slotv_jax.runs.presets import METHOD_TITLES, METHODS, PRESETS
from slotv_jax.training.config import MODELS


@cli.command(resumes=True)
def main(argv: Sequence[str] | None = None) -> int:
    p = cli.ArgumentParser(
        prog="python -m slotv_jax.experiments.sample_efficiency",
        description="SLOT-V vs T-REX sample efficiency (the paper's Fig. 3).",
    )
    p.add_argument("--preset", choices=sorted(PRESETS), default="quick")
    p.add_argument("--repeats", type=int, help="repeats per method (default: 10 paper, 3 quick)")
    p.add_argument("--every", type=int, default=10, help="updates between evaluations")
    p.add_argument("--val-size", type=int, default=1000, help="fixed trajectory_val subset")
    p.add_argument("--threshold", type=float, default=0.8)
    p.add_argument("--methods", nargs="+", choices=METHODS, default=list(METHODS))
    p.add_argument("--out", type=Path, help="default: runs/sample_efficiency_<preset>")
    p.add_argument("--cache", type=Path, default=Path("data"))
    p.add_argument("--compute-dtype", choices=("float32", "bfloat16"))
    p.add_argument(
        "--model",
        choices=MODELS,
        default="mlp",
        help="observer trained with SLOT-V's loss: the paper's network (mlp) or a parametric "
        "archetype (concepts: archetypes); T-REX keeps its network",
    )
    p.add_argument("--replot", action="store_true", help="only redraw the PNG of --out")
    distributed.add_cli_args(p)
    args = p.parse_args(argv)
    if args.replot:
        if args.out is None:
            p.error("--replot needs --out")
        replot(args.out)
        print(f"wrote {args.out}/sample_efficiency.png")
        return 0
    distributed.init_from_args(args)
    print(slotv_jax.XLA_CONFIG.summary(), file=sys.stderr)
    t0 = time.perf_counter()
    repeats = args.repeats or (10 if args.preset == "paper" else 3)
    for name in ("repeats", "every", "val_size"):
        v = repeats if name == "repeats" else getattr(args, name)
        if v < 1:
            p.error(f"--{name.replace('_', '-')}: expected an integer >= 1")
    suffix = "" if args.model == "mlp" else f"_{args.model}"
    out = args.out or Path("runs") / f"sample_efficiency_{args.preset}{suffix}"
    fileio.check_output_dir(out, ours=fileio.is_results_dir, resume=True)  # a rerun resumes
    doc = run(
        args.preset,
        out,
        repeats=repeats,
        every=args.every,
        val_size=args.val_size,
        threshold=args.threshold,
        methods=args.methods,
        cache=args.cache,
        compute_dtype=args.compute_dtype,
        model=args.model,
    )
    if not distributed.is_writer():
        return 0
    for method, s in doc["summary"].items():
        hit = s["examples_to_threshold_mean_curve"]
        print(
            f"{METHOD_TITLES[method]:>6s}: final accuracy {s['final_accuracy_mean']:.3f} ± "
            f"{s['final_accuracy_sd']:.3f}; "
            + (
                f"never reaches {args.threshold:.0%}"
                if hit is None
                else f"reaches {args.threshold:.0%} after {hit:,.0f} examples"
            )
            + f" (of {s['examples_per_epoch']:,} in the epoch)"
        )
    print(f"wrote {out}/sample_efficiency.{{csv,json,png}}; "
          f"this run took {time.perf_counter() - t0:.0f} s")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
