"""``python -m slotv_jax.experiments.planning``: the command line of the planning experiment."""

from __future__ import annotations

import dataclasses
import sys
from collections.abc import Sequence
from pathlib import Path

import slotv_jax
from slotv_jax.core import cli, fileio, validation
from slotv_jax.experiments.planning import ARCHETYPES, FAMILIES, LEARNED, PRESETS, run
from slotv_jax.experiments.planning_report import FIGURES, report, write_doc
from slotv_jax.runs import command
from slotv_jax.training import config as train_config


@cli.command(resumes=True)
def main(argv: Sequence[str] | None = None) -> int:
    p = cli.ArgumentParser(
        prog="python -m slotv_jax.experiments.planning",
        description="Plan legible motion with hand-crafted and learned observers; score it with "
        "the true labelers.",
    )
    p.add_argument("--preset", choices=sorted(PRESETS), default="quick")
    p.add_argument("--out", type=Path, help="results directory (default: runs/planning_<preset>)")
    p.add_argument("--cache", type=Path, default=Path("data"), help="dataset cache directory")
    for method in LEARNED:
        for family in FAMILIES:
            what = f"the {ARCHETYPES[family]} archetype" if method == "archetype" else method
            p.add_argument(
                f"--{method.replace('_', '-')}-{family}", type=Path, metavar="CKPT",
                help=f"checkpoint of {what} trained on {family} labels (default: train one)",
            )  # fmt: skip
    p.add_argument("--no-plus", action="store_true",
                   help="leave out SLOT-V+ and T-REX+ (plus_planners)")  # fmt: skip
    p.add_argument("--no-archetypes", action="store_true",
                   help="leave out the archetype observers (archetype_planners)")  # fmt: skip
    p.add_argument("--seed", type=int, default=0, help="training seed of the learned observers")
    p.add_argument("--n-scenes", type=int, help="held-out scenes per split (default: preset's)")
    p.add_argument("--iters", type=int, help="planner iterations (default: preset's)")
    p.add_argument("--budget", type=float, help="trust-region budget in m² (default: preset's)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a TrainConfig field of the SLOT-V and T-REX observers, e.g. "
                   "--set activation=softplus")  # fmt: skip
    p.add_argument("--compute-dtype", choices=train_config.COMPUTE_DTYPES,
                   help="matmul dtype of the observers' training (bfloat16 on GPUs)")  # fmt: skip
    p.add_argument("--doc", type=Path, help="also write the report here, figures beside it")
    args = p.parse_args(argv)
    validation.check_seeds("--seed", args.seed)
    print(slotv_jax.XLA_CONFIG.summary(), file=sys.stderr)

    cfg = dataclasses.replace(PRESETS[args.preset](), seed=args.seed)
    if args.n_scenes is not None:
        if args.n_scenes < 1:
            raise cli.InputError(f"--n-scenes: expected an integer >= 1, got {args.n_scenes}")
        cfg = dataclasses.replace(cfg, n_scenes=args.n_scenes)
    changes = {k: v for k, v in (("iters", args.iters), ("budget", args.budget)) if v is not None}
    if changes:
        try:
            cfg = dataclasses.replace(cfg, planner=dataclasses.replace(cfg.planner, **changes))
        except ValueError as e:
            raise cli.InputError(f"--iters/--budget: {e}") from None
    cfg = dataclasses.replace(cfg, train=command.retrained(cfg.train, args.compute_dtype, args.set))
    if args.no_archetypes:
        cfg = dataclasses.replace(cfg, archetype={})
    if args.no_plus:
        cfg = dataclasses.replace(cfg, plus=False)
    ckpts = {
        (m, f): getattr(args, f"{m}_{f}")
        for m in LEARNED
        for f in FAMILIES
        if getattr(args, f"{m}_{f}") is not None
    }
    out = args.out or Path("runs") / f"planning_{args.preset}"
    fileio.check_output_dir(out, ours=fileio.is_results_dir, resume=True)  # a rerun resumes
    if args.doc is not None:
        names = [args.doc.name, *(f"{args.doc.stem}_{f}" for f in FIGURES)]
        fileio.check_output_files(args.doc.parent, names, what="--doc")
    doc = run(cfg, out, checkpoints=ckpts, cache=args.cache)
    if args.doc is not None:
        write_doc(out, doc, args.doc)
    print(report(doc))
    print(f"results in {out / 'results.json'}; report in {out / 'planning.md'}; "
          f"{doc['timing']['total_s']:.0f} s")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
