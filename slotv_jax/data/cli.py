"""The command line of the dataset generator: ``python -m slotv_jax.data``."""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from slotv_jax.core import cli, fileio
from slotv_jax.core.defaults import LABELER_NAMES, SPLITS
from slotv_jax.core.xla import XLA_CONFIG
from slotv_jax.data.config import DATA_DISTRIBUTIONS, PRESETS, _config_from_json
from slotv_jax.data.generate import generate_dataset, relabel
from slotv_jax.data.storage import is_dataset_dir, load_split, save_split

# -------------------------------------------------------------------------- CLI


@cli.command(resumes=True)
def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m slotv_jax.data", description="Generate the seven SLOT-V dataset splits."
    )
    p.add_argument("--preset", choices=sorted(PRESETS), default="quick")
    p.add_argument("--out", required=True, type=Path, help="output directory")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--splits", nargs="+", choices=SPLITS, default=list(SPLITS))
    p.add_argument("--n-train", type=int, help="override the preset's train size")
    p.add_argument("--n-eval", type=int, help="override the preset's val/test size")
    p.add_argument("--chunk-size", type=int, help="trajectories per compiled call")
    p.add_argument(
        "--distribution",
        choices=sorted(DATA_DISTRIBUTIONS),
        default="default",
        help="named trajectory distribution and label temperatures (default: the one chosen "
        "by the fidelity ablation; spec_v1: the first version's)",
    )
    p.add_argument(
        "--relabel", action="store_true", help="recompute the labels of existing splits only"
    )
    for n in LABELER_NAMES:
        p.add_argument(f"--beta-{n}", type=float, help=f"inverse temperature of {n}")
    p.add_argument("--camera", help="camera of the Nikolaidis labeler")
    args = p.parse_args(argv)
    if args.relabel and not is_dataset_dir(args.out):
        raise cli.InputError(f"--out {args.out}: holds no dataset splits to --relabel")
    # a dataset of ours is resumed (finished splits are kept); anything else is refused
    fileio.check_output_dir(args.out, ours=is_dataset_dir, resume=True)
    print(XLA_CONFIG.summary(), file=sys.stderr)

    label_kw = {f"beta_{n}": getattr(args, f"beta_{n}") for n in LABELER_NAMES}
    label_kw["camera"] = args.camera
    label_kw = {k: v for k, v in label_kw.items() if v is not None}
    if args.relabel:
        for name in args.splits:
            split = load_split(args.out, name)
            cfg = _config_from_json(split.meta["config"])
            labels = dataclasses.replace(cfg.labels, **label_kw)
            cfg = dataclasses.replace(cfg, labels=labels)
            meta = {k: v for k, v in split.meta.items() if k in ("reachability", "timing_s")}
            split = relabel(dataclasses.replace(split, meta=meta), labels)
            save_split(args.out, split, cfg)
            print(f"{name}: relabelled with {dataclasses.asdict(labels)}")
        return 0

    traj, labels = DATA_DISTRIBUTIONS[args.distribution]
    overrides = {"seed": args.seed, "trajectory": traj, "labels": labels}
    if args.n_train is not None:
        overrides["n_train"] = args.n_train
    if args.n_eval is not None:
        overrides["n_eval"] = args.n_eval
    if args.chunk_size is not None:
        overrides["chunk_size"] = args.chunk_size
    if label_kw:
        overrides["labels"] = dataclasses.replace(labels, **label_kw)
    cfg = PRESETS[args.preset](**overrides)
    t0 = time.perf_counter()
    data = generate_dataset(cfg, args.out, splits=args.splits)
    dt = time.perf_counter() - t0
    for name, s in data.items():
        r = s.meta["reachability"]
        print(
            f"{name:>16s}: {len(s):>7d} trajectories, {s.scene_goals.shape[0]:>3d} scenes, "
            f"trajectory rejection {r['trajectory_rejection_rate']:.2%}, "
            f"scene rejection {r['scenes']['rejection_rate']:.2%}"
        )
    print(f"wrote {args.out} in {dt:.1f} s (config digest {cfg.digest()})")
    return 0
