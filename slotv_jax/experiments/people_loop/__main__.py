"""``python -m slotv_jax.experiments.people_loop``: the command line of the people loop
(the package docstring)."""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import jax

from slotv_jax.core import cli, fileio, validation
from slotv_jax.core.xla import XLA_CONFIG
from slotv_jax.experiments.people_loop import (
    FAMILIES,
    PRESETS,
    LoopConfig,
    draw_example,
    is_results,
    report_lib,
    run,
    share_gpu_memory,
    stem_of,
)
from slotv_jax.observers import people as people_lib
from slotv_jax.observers import zoo
from slotv_jax.runs import command

# ------------------------------------------------------------------ command line


def add_cache_flag(ap: argparse.ArgumentParser) -> None:
    ap.add_argument(
        "--cache",
        "--data-cache",
        dest="data_cache",
        default="data",
        help="where datasets (and, under xla/, compiled programs) are cached",
    )


def parser() -> argparse.ArgumentParser:
    ap = cli.ArgumentParser(
        prog="python -m slotv_jax.experiments.people_loop",
        description="Simulated people's answers -> observers -> legible plans -> evaluation.",
    )
    ap.add_argument("--preset", choices=sorted(PRESETS), default="quick")
    ap.add_argument(
        "--population",
        default="default",
        help="comma-separated: default, homogeneous, random:K (the K-th draw of the "
        "hyper-distribution), suite (default, homogeneous and the suite's draws), "
        "population JSON files, a zoo member (people outside the population model: "
        + ", ".join(zoo.zoo_names())
        + "), zoo (every member), or module:function (your own people: a function "
        "returning a slotv_jax.observers.zoo.ZooMember)",
    )
    ap.add_argument(
        "--out", default=str(report_lib.DEFAULT_OUT), help="folder of the results and report"
    )
    add_cache_flag(ap)
    ap.add_argument("--seeds", type=int, help="number of seeds (default: the preset's)")
    ap.add_argument("--first-seed", type=int, help="first seed (default 0)")
    ap.add_argument("--strategies", help="comma-separated (random first), e.g. random,margin")
    ap.add_argument("--families", help=f"comma-separated of {','.join(FAMILIES)}")
    ap.add_argument("--sizes", help="comma-separated answer counts, e.g. 250,500,1000")
    ap.add_argument("--problems", type=int, help="held-out planning problems")
    ap.add_argument(
        "--plan-share",
        type=float,
        help="share of every round after the first asked about the planner's own plans of "
        "the study's scenes (0 to 1; default: the preset's)",
    )
    ap.add_argument(
        "--caution",
        type=float,
        help="κ of the cautious pick (family pick_cautious): the standard deviations of its "
        "ensemble's log P(target) the planner holds back (>= 0; default: the preset's)",
    )
    ap.add_argument(
        "--processes",
        type=int,
        default=1,
        help="spread the (population, seed) runs over this many worker processes, dealt to "
        "the visible GPUs in turn (worker i on GPU i mod G; default 1)",
    )
    ap.add_argument("--worker-jobs", help=argparse.SUPPRESS)  # a worker's share (JSON)
    ap.add_argument("--report", action="store_true", help="only render the report again")
    ap.add_argument("--no-progress", action="store_true", help="no progress bars")
    return ap


def config_from(args: argparse.Namespace) -> LoopConfig:
    """The preset with the command line's overrides (checked by :class:`LoopConfig`)."""
    cfg = PRESETS[args.preset]()
    change = {}
    validation.check_seeds(
        "--first-seed",
        cfg.first_seed if args.first_seed is None else args.first_seed,
        cfg.seeds if args.seeds is None else args.seeds,
        count_name="--seeds",
    )
    if args.seeds is not None:
        change["seeds"] = args.seeds
    if args.first_seed is not None:
        change["first_seed"] = args.first_seed
    if args.problems is not None:
        change["problems"] = args.problems
    if args.plan_share is not None:
        change["plan_share"] = args.plan_share
    if args.caution is not None:
        change["caution"] = args.caution
    for name in ("strategies", "families"):
        v = getattr(args, name)
        if v is not None:
            change[name] = tuple(x.strip() for x in v.split(",") if x.strip())
            twice = [x for x in dict.fromkeys(change[name]) if change[name].count(x) > 1]
            if twice:
                raise ValueError(f"--{name} {v}: expected each name once, {twice[0]!r} is twice")
    if args.sizes is not None:
        try:
            change["sizes"] = tuple(int(x) for x in args.sizes.split(","))
        except ValueError:
            raise ValueError(
                f"--sizes: expected comma-separated integers, got {args.sizes!r}"
            ) from None
    return dataclasses.replace(cfg, **change)


def config_flags(args: argparse.Namespace) -> list[str]:
    """The flags that make :func:`config_from`'s config (for a spread run's workers)."""
    out = ["--preset", args.preset]
    for flag in ("strategies", "families", "sizes", "problems", "plan_share", "caution"):
        v = getattr(args, flag)
        if v is not None:
            out += [f"--{flag.replace('_', '-')}", str(v)]
    return out


def use_compilation_cache(path: Path) -> str | None:
    """Keep this process's compiled programs in ``path`` (JAX's persistent compilation
    cache, ``jax_compilation_cache_dir``), so that the next process of the same program,
    shapes and JAX version loads them instead of compiling again; where
    ``$JAX_COMPILATION_CACHE_DIR`` is set, JAX already uses it and it is kept. A file of
    that name is left alone and nothing is kept (one line says so; None). Returns the
    folder in use. Only for the command's entry point: JAX starts its cache once per
    process, at the first compilation."""
    if os.environ.get("JAX_COMPILATION_CACHE_DIR"):
        return os.environ["JAX_COMPILATION_CACHE_DIR"]
    if path.exists() and not path.is_dir():
        print(f"people loop: {path} is not a folder; compiled programs are not kept",
              file=sys.stderr)  # fmt: skip
        return None
    jax.config.update("jax_compilation_cache_dir", str(path))
    return str(path)


def data_cache(argv: Sequence[str]) -> Path:
    """The ``--cache`` folder of a command line (its default where the flag is missing or
    malformed: :func:`main` says what is wrong with it)."""
    ap = argparse.ArgumentParser(add_help=False, exit_on_error=False)
    add_cache_flag(ap)
    try:
        return Path(ap.parse_known_args(argv)[0].data_cache)
    except argparse.ArgumentError:
        return Path("data")


@cli.command(resumes=True)
def main(argv: Sequence[str] | None = None) -> int:
    args = parser().parse_args(argv)
    if args.processes > 1:  # before the first JAX operation, which takes the GPUs' memory
        share_gpu_memory(os.environ)
    cfg = config_from(args)
    specs = people_lib.expand(args.population.split(","))
    if not specs:
        raise ValueError("--population: expected at least one population")
    for p in specs:  # every population file and --people is read and checked before any work
        people_lib.get_people(p)
    if not 1 <= args.processes <= 64:
        raise ValueError(f"--processes: expected 1..64, got {args.processes}")
    out = Path(args.out)
    stem = stem_of(cfg.preset)
    names = [
        f"{stem}{s}"
        for s in ("_results.json", ".md", ".png", "_plans.npz", "_render.png", "_fit_plan.png")
    ]
    fileio.check_output_files(out, names, ours={names[0]: is_results}, beside=names[0])
    if args.report:  # the report and the example drawn again from the document alone

        def again(doc: dict, _command: str) -> None:
            report_lib.render(doc, out, stem)
            draw_example(report_lib.finished(doc)[0], out, stem, again=True)

        return command.render_again(out, stem, is_results, again, "")
    out.mkdir(parents=True, exist_ok=True)
    print(XLA_CONFIG.summary(), file=sys.stderr)
    t0 = time.perf_counter()
    jobs = None
    if args.worker_jobs is not None:
        jobs = json.loads(args.worker_jobs)
    run(
        cfg,
        out,
        specs,
        cache=Path(args.data_cache),
        progress=not args.no_progress,
        processes=args.processes,
        jobs=jobs,
        worker_flags=config_flags(args),
    )
    print(
        f"people loop: {time.perf_counter() - t0:.0f} s; report {out / (stem + '.md')}",
        file=sys.stderr,
    )
    return 0


if __name__ == "__main__":
    # The command's compiled programs are kept beside its datasets (--cache), for the next
    # run and for a spread run's other workers: the families' planner, the fits and the
    # judges do not depend on the population (experiments/BENCHMARKS.md: the GPU time saved).
    use_compilation_cache(data_cache(sys.argv[1:]) / "xla")
    sys.exit(main())
