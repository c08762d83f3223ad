"""The command line of ``python -m slotv_jax.train`` (:ref:`concepts-public-names`,
:ref:`concepts-archetypes`).

    python -m slotv_jax.train --data DIR --labeler NAME --method {slotv,trex} \
        --preset {quick,paper} --out CKPT [--model {mlp,dragan,viewpoint,mixture}]
    python -m slotv_jax.train --study FILE --method slotv --out CKPT [--cv K]

Trains one model on a generated dataset (or on a study's answers,
:func:`slotv_jax.study.train_main`), writes an Orbax checkpoint with its JSON config
after every epoch (:mod:`slotv_jax.training.checkpoint`), and reports the accuracy on the four
Table 1 splits. It drives :mod:`slotv_jax.train`, :mod:`slotv_jax.data`,
:mod:`slotv_jax.training.checkpoint` and :mod:`slotv_jax.study`, so it sits above all of them;
``slotv_jax/train.py`` runs :func:`main` when executed as a script.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import time
from collections.abc import Sequence
from pathlib import Path

import jax
import numpy as np

from slotv_jax import data as data_lib
from slotv_jax.core import cli, fileio, validation
from slotv_jax.core.defaults import LABELER_NAMES, TEST_SPLITS
from slotv_jax.core.xla import XLA_CONFIG
from slotv_jax.study import cli as study_cli
from slotv_jax.training import checkpoint, evaluate
from slotv_jax.training import config as train_config
from slotv_jax.training.trainer import make_train, packed_trainer
from slotv_jax.training.types import prepare, trim_goals


def _parse_args(argv):
    ap = cli.ArgumentParser(
        prog="python -m slotv_jax.train",
        description="Train one SLOT-V or T-REX model on a generated dataset and save a checkpoint.",
    )
    ap.add_argument("--data", help="dataset directory (python -m slotv_jax.data)")
    ap.add_argument("--labeler", choices=LABELER_NAMES)
    ap.add_argument(
        "--study", help="train on a study file instead (.npz, python -m slotv_jax.study import)"
    )
    ap.add_argument("--condition", default=None, help="--study: use this condition's answers")
    ap.add_argument("--cv", type=int, default=0, help="--study: also run K-fold cross-validation")
    ap.add_argument("--method", required=True, choices=train_config.METHODS)
    ap.add_argument("--preset", default="quick", choices=tuple(train_config.PRESETS))
    ap.add_argument(
        "--model", default="mlp", choices=train_config.MODELS,
        help="observer: the paper's network (mlp) or a parametric archetype (concepts: archetypes; "
        "needs --method slotv; its preset is config.archetype)",
    )  # fmt: skip
    ap.add_argument("--out", required=True, help="checkpoint directory to write")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--epochs", type=int, default=None, help="override the preset's epochs")
    ap.add_argument("--compute-dtype", default=None, choices=train_config.COMPUTE_DTYPES)
    ap.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE",
        help="override any TrainConfig field, e.g. --set hidden=256,128 --set learning_rate=0.01",
    )  # fmt: skip
    ap.add_argument(
        "--init", metavar="CKPT",
        help="start from this checkpoint's parameters (the same --model and --method, e.g. "
        "trained on a dataset's labels) instead of a random draw",
    )  # fmt: skip
    ap.add_argument(
        "--resume", action="store_true", help="continue the checkpoint at --out if it exists"
    )
    ap.add_argument(
        "--overwrite", action="store_true", help="replace the checkpoint at --out (not --resume)"
    )
    ap.add_argument("--no-progress", action="store_true")
    args = ap.parse_args(argv)
    if args.study is None and (args.data is None or args.labeler is None):
        ap.error("give --data and --labeler (a generated dataset), or --study FILE")
    if args.study is not None and (args.data is not None or args.labeler is not None):
        ap.error("--study replaces --data and --labeler; give one or the other")
    return args


@cli.command
def main(argv: Sequence[str] | None = None) -> int:
    """CLI entry point: train, checkpoint after every epoch, report test accuracies.

    Before any work it checks ``--out`` (:func:`slotv_jax.core.fileio.check_output_dir`): an
    existing checkpoint is continued with ``--resume`` or replaced with ``--overwrite``;
    anything else in the way is refused.
    """
    args = _parse_args(argv)
    validation.check_seeds("--seed", args.seed)
    if args.epochs is not None and args.epochs < 1:
        raise cli.InputError(f"--epochs: expected an integer >= 1, got {args.epochs}")
    cfg = train_config.preset(args.preset, args.method, model=args.model)
    if args.epochs is not None:
        cfg = dataclasses.replace(cfg, epochs=args.epochs)
    if args.compute_dtype is not None:
        cfg = dataclasses.replace(cfg, compute_dtype=args.compute_dtype)
    cfg = train_config.apply_overrides(cfg, args.set)
    fileio.check_not_input(args.out, {"--data": args.data, "--study": args.study},
                           replaces_dir=True)  # fmt: skip
    fileio.check_output_dir(
        args.out, ours=checkpoint.exists, resume=args.resume, overwrite=args.overwrite,
        resume_hint="pass --resume to continue training it",
    )  # fmt: skip
    if args.overwrite:
        args.resume = False
    args.init_params = None
    if args.init is not None:
        if args.resume and checkpoint.exists(args.out):
            raise cli.InputError(
                "--init: --resume continues the checkpoint at --out from its own parameters; "
                "give one or the other"
            )
        fileio.check_not_input(args.out, {"--init": args.init}, replaces_dir=True)
        try:
            args.init_params = checkpoint.initial_params(args.init, cfg)
        except ValueError as e:
            raise cli.InputError(f"--init {args.init}: {e}") from None
    print(XLA_CONFIG.summary(), flush=True)
    if args.study is not None:
        return study_cli.train_main(cfg, args)
    out = Path(args.out)

    # Every split this run reads (and its labels), before any training: a missing or
    # corrupt one is an error now, not after the last epoch.
    splits = {name: data_lib.load_split(args.data, name) for name in TEST_SPLITS}
    evals = {
        name: prepare(split, args.labeler, size=cfg.train_size if name == "train" else None)
        for name, split in splits.items()
    }
    data = trim_goals(evals["train"])
    trainer = make_train(cfg, progress=not args.no_progress)
    if args.resume and checkpoint.exists(out):
        _, state, meta = checkpoint.restore(out, cfg)
        print(f"resuming from {out} after epoch {int(state.epoch)}", flush=True)
    else:
        state = trainer.init(jax.random.key(args.seed), args.init_params)  # θ₀: --init's
        meta = {} if args.init_params is None else {"init": str(args.init)}
    trainer = packed_trainer(trainer, state.key, data, range(int(state.epoch), cfg.epochs))
    print(f"devices: {trainer.mesh.size} × {trainer.platform}; "
          f"backward: {trainer.backward}; packed pairs: {trainer.packed_pairs or 'off'}; "
          f"config: {json.dumps(cfg.used_dict(), sort_keys=True)}", flush=True)  # fmt: skip
    run_epoch = jax.jit(functools.partial(trainer.run, epochs=1), donate_argnums=0)
    data = trainer.replicate(data)
    state = trainer.replicate(state)
    t0 = time.perf_counter()
    while int(state.epoch) < cfg.epochs:
        state, metrics = run_epoch(state, data)
        loss = float(np.asarray(metrics.loss)[-1].mean())
        print(f"epoch {int(state.epoch)}/{cfg.epochs}: loss {loss:.4f}", flush=True)
        meta = {**meta, "labeler": args.labeler, "seed": args.seed, "data": str(args.data)}
        checkpoint.save(out, cfg, state, meta=meta)
    train_s = time.perf_counter() - t0

    acc = {}
    for name in TEST_SPLITS:
        acc[name] = float(evaluate.accuracy(cfg, state.params, evals[name]))
        print(f"accuracy {name}: {acc[name]:.4f}", flush=True)
    meta = {**meta, "accuracy": acc, "train_seconds": round(train_s, 2)}
    if cfg.model != "mlp":  # the fitted parameters, in the checkpoint and in words
        fitted = trainer.model(state.params)
        meta["parameters"] = fitted.parameters()
        print(fitted.describe(), flush=True)
    checkpoint.save(out, cfg, state, meta=meta)
    print(json.dumps({"checkpoint": str(out), "accuracy": acc}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
