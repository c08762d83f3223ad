"""The command line of studies: ``python -m slotv_jax.study`` (import, show, train, cv, pick;
stimuli, serve, export, simulate: :mod:`slotv_jax.webstudy.web_cli`)."""

from __future__ import annotations

import argparse
import dataclasses
import json
import shutil
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import jax

from slotv_jax.answers import pick as pick_lib
from slotv_jax.answers import pool_file
from slotv_jax.answers.crossval import cross_validate, cv_table, fit_beta, model_metrics
from slotv_jax.answers.fitting import study_trainer, train_study
from slotv_jax.answers.storage import load_study, save_study
from slotv_jax.answers.tables import read_tables
from slotv_jax.core import cli, fileio, validation
from slotv_jax.core.fileio import write_text
from slotv_jax.planning import caution as caution_lib
from slotv_jax.planning.plans import save_plans
from slotv_jax.study import rounds
from slotv_jax.training import checkpoint
from slotv_jax.training import config as train_config
from slotv_jax.training.config import TrainConfig
from slotv_jax.webstudy import web_cli
from slotv_jax.world import scene

# ===================================================================== CLI


def train_main(cfg: TrainConfig, args: argparse.Namespace) -> int:
    """``python -m slotv_jax.train --study FILE ...``: train any observer (``--model`` mlp or
    an archetype; SLOT-V or T-REX) on a study's answers, each row scored on the points its
    participants saw (:func:`slotv_jax.answers.fitting.prefix_scores`), checkpoint every
    epoch, optionally cross-validate (``--cv K``), and print the metrics (an archetype's
    fitted parameters too). A study with fewer answer rows than the preset's batch trains
    with the largest power of two that fits (and says so), unless ``--set batch_size=N``
    is given."""
    study = load_study(args.study)
    if args.condition is not None:
        study = study.select_condition(args.condition)
    cfg = dataclasses.replace(cfg, train_size=None)
    chosen = any(a.split("=", 1)[0].strip() == "batch_size" for a in getattr(args, "set", []))
    if not chosen and study.n_rows < cfg.batch_size:  # a small study: a batch that fits
        fit = 1 << (study.n_rows.bit_length() - 1)
        print(
            f"batch_size: the study has {study.n_rows} answer rows, fewer than the preset's "
            f"{cfg.batch_size}; using batch_size={fit} (--set batch_size=N to choose)"
        )
        cfg = dataclasses.replace(cfg, batch_size=fit)
    print(study.summary(), flush=True)
    print(f"config: {json.dumps(cfg.used_dict(), sort_keys=True)}", flush=True)
    out = Path(args.out)
    meta: dict[str, Any] = {"study": str(args.study), "condition": args.condition,
                            "seed": args.seed}  # fmt: skip
    state = None
    if args.resume and checkpoint.exists(out):
        _, state, old = checkpoint.restore(out, cfg)
        meta = {**old, **meta}
        print(f"resuming from {out} after epoch {int(state.epoch)}", flush=True)
    elif getattr(args, "init_params", None) is not None:  # fine-tuning: θ₀ from --init
        state = study_trainer(cfg).init(jax.random.key(args.seed), args.init_params)
        meta["init"] = str(args.init)

    def save(st, loss):
        print(f"epoch {int(st.epoch)}/{cfg.epochs}: loss {loss:.4f}", flush=True)
        checkpoint.save(out, cfg, st, meta=meta)

    t0 = time.perf_counter()
    state = train_study(cfg, study, jax.random.key(args.seed), progress=not args.no_progress,
                        on_epoch=save, state=state)  # fmt: skip
    meta["train_seconds"] = round(time.perf_counter() - t0, 2)
    meta["train_metrics"] = model_metrics(cfg, state.params, study)
    print(f"training rows: accuracy {meta['train_metrics']['accuracy']:.4f}, NLL per answer "
          f"{meta['train_metrics']['nll_per_answer']:.4f}", flush=True)  # fmt: skip
    if cfg.model != "mlp":  # an archetype: its fitted parameters, in the checkpoint and in words
        fitted = study_trainer(cfg).model(state.params)
        meta["parameters"] = fitted.parameters()
        print(fitted.describe(), flush=True)
    if args.cv:
        cv = cross_validate(cfg, study, folds=args.cv, seed=args.seed,
                            progress=not args.no_progress)  # fmt: skip
        meta["cross_validation"] = {k: v for k, v in cv.items() if k != "per_fold"}
        print(cv_table(cv), flush=True)
    checkpoint.save(out, cfg, state, meta=meta)
    print(json.dumps({"checkpoint": str(out), "train_seconds": meta["train_seconds"]}))
    return 0


def _parse_args(argv):
    ap = cli.ArgumentParser(
        prog="python -m slotv_jax.study",
        description="Study data: import answer tables, show a study file, cross-validate; "
        "run a study: render stimuli, serve them, export the answers, simulate participants, "
        "choose the next round.",
    )
    sub = ap.add_subparsers(dest="command", required=True)
    imp = sub.add_parser("import", help="tables (CSV/JSON) -> one study .npz")
    imp.add_argument("--trajectories", required=True, help="trajectory,x,y,z[,t] per point")
    imp.add_argument("--goals", required=True, help="[trajectory,]goal,x,y,z per goal")
    imp.add_argument("--answers", required=True, help="trajectory,guess[,tau,participant,...]")
    imp.add_argument("--out", required=True, help="study file to write (.npz)")
    imp.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    imp.add_argument("--ignore-columns", default="", metavar="A,B",
                     help="extra columns to leave out on purpose (any other unknown column "
                     "is refused)")  # fmt: skip
    show = sub.add_parser("show", help="validate a study file and summarise it")
    show.add_argument("study")
    cv = sub.add_parser("cv", help="k-fold cross-validation of SLOT-V/T-REX and baselines")
    cv.add_argument("study")
    cv.add_argument("--methods", default="slotv", help="comma-separated: slotv,trex")
    cv.add_argument("--preset", default="quick", choices=tuple(train_config.PRESETS))
    cv.add_argument("--folds", type=int, default=5)
    cv.add_argument("--seed", type=int, default=0)
    cv.add_argument("--epochs", type=int, default=None)
    cv.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    cv.add_argument("--condition", default=None)
    cv.add_argument("--out", default=None, help="write the results as JSON here")
    cv.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    pk = sub.add_parser(
        "pick",
        help="the observer to plan with, chosen by the held-out likelihood of answers "
        "or by judging every candidate's plans",
    )
    pk.add_argument("study")
    pk.add_argument("--out", required=True, help="checkpoint folder of the pick")
    pk.add_argument("--candidates", default=",".join(pick_lib.DEFAULT_CANDIDATES),
                    help="comma-separated families and labelers to choose from")  # fmt: skip
    pk.add_argument(
        "--preset", default="quick", choices=tuple(train_config.PRESETS),
        help="the candidates' training and, for --by plans or pool, the planner: "
        + "; ".join(f"{p} {pick_lib.planner_words(p)} per plan" for p in pick_lib.PLANNERS)
        + " (default: quick)",
    )  # fmt: skip
    pk.add_argument("--by", default="likelihood", choices=pick_lib.BY,
                    help="likelihood: the pool's largest weight on held-out answers; plans: "
                    "the candidate whose plans of the study's scenes the other fits judge "
                    "the most legible (also writes DIR/plans.npz); pool: the people loop's "
                    "pick, the pool less the candidate of the least-judged plans, written "
                    "as DIR/pool.json and its members (also writes DIR/plans.npz)")  # fmt: skip
    pk.add_argument("--problems", type=int, default=12,
                    help="--by plans or pool: at most this many of the study's (scene, goal) "
                    "problems are planned")  # fmt: skip
    pk.add_argument("--caution", type=float, default=None,
                    help="--by pool: also plan the pool for a lower confidence bound over its "
                    "folds' fits and its fits on every answer, this many standard deviations "
                    "held back (plans.npz's pool_cautious; default: not planned)")  # fmt: skip
    pk.add_argument("--folds", type=int, default=3)
    pk.add_argument("--seed", type=int, default=0)
    pk.add_argument("--condition", default=None)
    pk.add_argument("--camera", default="observer",
                    help="the camera the study's people watched, for the Nikolaidis candidate "
                    "and the motion reader: a camera of the scene or the lab's camera file "
                    "(*.json)")  # fmt: skip
    pk.add_argument("--overwrite", action="store_true", help="replace an earlier pick")
    pk.add_argument("--no-progress", action="store_true")
    web_cli.add_commands(sub)
    rounds.add_command(sub)
    return ap.parse_args(argv)


def pick_main(args: argparse.Namespace) -> int:
    """``python -m slotv_jax.study pick STUDY --out DIR``: score every candidate by the
    held-out likelihood of the study's answers (folds by motion), print the table, fit the
    pick (the pool's largest weight) on every answer and write it: a learned family as a
    checkpoint (``slotv_jax.load_observer(DIR)``; the table in its JSON config), a labeler
    as ``DIR/pick.json`` with its fitted β (``planning.labeler_observer(name, beta=β)``).
    ``--by plans``: the pick by plans instead (:func:`slotv_jax.answers.pick.pick_by_plans`),
    and ``DIR/plans.npz``, every candidate's plans of the study's scenes; ``--by pool``:
    the people loop's pick (:func:`slotv_jax.answers.pick.pick_pool`), written as the pool
    itself (``DIR/pool.json`` and its members, :func:`slotv_jax.answers.load_pool`: the
    observer the loop plans against), and the plans, the pool's own among them. The output
    is written beside and swapped in whole (an earlier pick of ``--overwrite`` leaves
    nothing)."""
    validation.check_seeds("--seed", args.seed)
    names = pick_lib.check_candidates([c.strip() for c in args.candidates.split(",")])
    fileio.check_not_input(args.out, {"study": args.study})

    def ours(p):
        return checkpoint.exists(p) or (Path(p) / "pick.json").is_file() or pool_file.is_pool(p)

    fileio.check_output_dir(args.out, ours=ours, overwrite=args.overwrite)
    if not (isinstance(args.problems, int) and args.problems >= 1):
        raise ValueError(f"--problems: expected an int >= 1, got {args.problems!r}")
    if args.caution is not None:
        if args.by != "pool":
            raise ValueError(f"--caution: plans the pool's bound, so it needs --by pool, got "
                             f"--by {args.by}")  # fmt: skip
        try:
            caution_lib.check_caution(args.caution)
        except ValueError as e:
            raise ValueError(f"--{e}") from None
    try:
        scene.check_camera(args.camera)
    except ValueError as e:
        raise ValueError(f"--camera: {e}") from None
    if args.by != "likelihood":  # what the plans are made with, before the work
        print(pick_lib.planner_line(args.preset), flush=True)
    study = load_study(args.study)
    if args.condition is not None:
        study = study.select_condition(args.condition)
    progress = not args.no_progress
    fits, arrays = {}, None
    if args.by == "plans":
        rep, fits, arrays = pick_lib.pick_by_plans(
            study, names, preset=args.preset, seed=args.seed, problems=args.problems,
            progress=progress, camera=args.camera,
        )  # fmt: skip
        print(pick_lib.plans_table(rep), flush=True)
    elif args.by == "pool":
        rep, fits, arrays, by_plans = pick_lib.pick_pool(
            study, names, preset=args.preset, folds=args.folds, seed=args.seed,
            problems=args.problems, progress=progress, camera=args.camera,
            caution=args.caution,
        )  # fmt: skip
        print(pick_lib.plans_table(by_plans), "", pick_lib.pick_table(rep), sep="\n", flush=True)
    else:
        rep = pick_lib.pick_study(study, names, preset=args.preset, folds=args.folds,
                                  seed=args.seed, progress=progress,
                                  camera=args.camera)  # fmt: skip
        print(pick_lib.pick_table(rep), flush=True)
    out, winner = Path(args.out), rep["pick"]
    meta = {"study": str(args.study), "condition": args.condition, "camera": args.camera,
            "pick": rep}  # fmt: skip
    tmp = fileio.temp_dir_beside(out)  # the whole output, then swapped in: nothing stale
    try:
        if args.by == "pool":  # the pool itself, what the people loop plans against
            weights = dict(zip(rep["candidates"], rep["weights"], strict=True))
            kept = pool_file.save_pool(tmp, fits, weights, meta=meta, camera=args.camera)
            said = (
                "pick: the pool of "
                + ", ".join(f"{n} (weight {weights[n]:.3g})" for n in kept)
                + f", each fitted on every answer: {out} (slotv_jax.answers.load_pool)"
            )
        elif winner in pick_lib.LABELERS:
            beta = (fits[winner]["beta"] if winner in fits
                    else fit_beta(study, winner, camera=args.camera)[0])  # fmt: skip
            write_text(tmp / "pick.json", json.dumps({**meta, "labeler": winner, "beta": beta}))
            said = (
                f"pick: {winner} with β = {beta:.4g} (fitted on every answer): {out / 'pick.json'}"
            )
        else:
            if winner in fits:  # the pick by plans fitted it on every answer already
                cfg, state = fits[winner]["cfg"], fits[winner]["state"]
            else:
                cfg = pick_lib.fit_config(args.preset, winner, study.n_rows, args.camera)
                start = pick_lib.starts(study, [winner], preset=args.preset, camera=args.camera)
                state = pick_lib.fit(cfg, study, jax.random.key(args.seed), start.get(winner))
            checkpoint.save(tmp, cfg, state, meta=meta)
            said = f"pick: {winner}, fitted on every answer: {out} (slotv_jax.load_observer)"
        if arrays is not None:
            save_plans(tmp / "plans.npz", arrays)
        fileio.replace_dir(tmp, out)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    print(said)
    if arrays is not None:
        whose = "every candidate's and the pool's" if args.by == "pool" else "every candidate's"
        if args.by == "pool" and args.caution is not None:
            whose += f" (pool_cautious: the pool's lower bound, κ = {args.caution:g})"
        print(f"plans: the straight line and {whose}: {out / 'plans.npz'} "
              "(study stimuli --plans, render --plans)")  # fmt: skip
    return 0


@cli.command
def main(argv: Sequence[str] | None = None) -> int:
    """CLI: ``import`` (report what was read), ``show``, ``cv``; input errors in one line."""
    args = _parse_args(argv)
    if args.command in web_cli.COMMANDS:
        return web_cli.COMMANDS[args.command](args)
    if args.command == "next":
        return rounds.next_main(args)
    if args.command == "pick":
        return pick_main(args)
    if args.command == "cv":
        validation.check_seeds("--seed", args.seed)
    if getattr(args, "out", None) is not None:  # before any work: never over an input
        if args.command == "import":
            inputs = {f"--{k}": getattr(args, k) for k in ("trajectories", "goals", "answers")}
        else:
            inputs = {"study": args.study}
        fileio.check_not_input(args.out, inputs)
        suffix = {"import": ".npz", "cv": ".json"}[args.command]
        fileio.check_output_file(args.out, overwrite=args.overwrite, suffix=suffix)
    if args.command == "import":
        ignore = args.ignore_columns.split(",")
        study, report = read_tables(
            args.trajectories, args.goals, args.answers, ignore_columns=ignore
        )
        save_study(args.out, study)
        print(report.describe(study))
        print(f"wrote {args.out}")
        return 0
    if args.command == "show":
        print(load_study(args.study).summary())
        return 0
    study = load_study(args.study)
    if args.condition is not None:
        study = study.select_condition(args.condition)
    cfgs = {}
    for m in args.methods.split(","):
        c = train_config.preset(args.preset, m.strip(), train_size=None)
        if args.epochs is not None:
            c = dataclasses.replace(c, epochs=args.epochs)
        cfgs[m.strip()] = train_config.apply_overrides(c, args.set)
    cv = cross_validate(cfgs, study, folds=args.folds, seed=args.seed)
    print(cv_table(cv))
    if args.out:
        write_text(args.out, json.dumps(cv, indent=2))
    return 0
