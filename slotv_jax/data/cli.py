"""The command line of the dataset generator: ``python -m slotv_jax.data``."""

from __future__ import annotations

import dataclasses
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from slotv_jax.core import cli, fileio, validation
from slotv_jax.core.defaults import LABELER_NAMES, SPLITS
from slotv_jax.core.xla import XLA_CONFIG
from slotv_jax.data.config import DATA_DISTRIBUTIONS, PRESETS, _config_from_json, config_for
from slotv_jax.data.generate import generate_dataset, relabel
from slotv_jax.data.storage import (
    DEFAULT_CACHE,
    _check_dir_config,
    _read_json,
    dataset_dir,
    find_dataset,
    has_split,
    is_dataset_dir,
    load_split,
    preset_dir,
    save_split,
)
from slotv_jax.world import scene

# -------------------------------------------------------------------------- CLI


@cli.command(resumes=True)
def main(argv: Sequence[str] | None = None) -> int:
    p = cli.ArgumentParser(
        prog="python -m slotv_jax.data",
        description="Generate the seven SLOT-V dataset splits. Without --out they go to the "
        f"cache that the main job uses, {DEFAULT_CACHE}/<preset>-<config digest>, where every "
        "command finds them by the preset's name (--data quick).",
    )
    p.add_argument("--preset", choices=sorted(PRESETS), default="quick")
    p.add_argument(
        "--out",
        type=Path,
        help=f"output directory (default: the cache, {DEFAULT_CACHE}/<preset>-<digest>)",
    )
    p.add_argument(
        "--data",
        help="--relabel: the dataset to relabel, a folder or a preset name (default: --out)",
    )
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
        "--relabel",
        action="store_true",
        help="recompute the labels of existing splits only (of --data, into --out)",
    )
    for n in LABELER_NAMES:
        p.add_argument(f"--beta-{n}", type=float, help=f"inverse temperature of {n}")
    p.add_argument("--camera", help="camera of the Nikolaidis labeler")
    args = p.parse_args(argv)
    validation.check_seeds("--seed", args.seed)

    label_kw = {f"beta_{n}": getattr(args, f"beta_{n}") for n in LABELER_NAMES}
    label_kw["camera"] = args.camera
    if args.camera is not None and scene.is_camera_file(args.camera):
        # a dataset is cached by its config, which would name the file and not what it says
        raise cli.InputError(
            f"--camera {args.camera}: a dataset's labels take a camera of the scene "
            f"({', '.join(scene.CAMERAS)}); label motions from a lab's camera file with "
            "python -m slotv_jax.labelers --camera FILE"
        )
    label_kw = {k: v for k, v in label_kw.items() if v is not None}
    if args.relabel:
        return _relabel(args, label_kw)
    if args.data is not None:
        raise cli.InputError("--data: only with --relabel (the dataset to relabel)")

    overrides = {"seed": args.seed}
    for k in ("n_train", "n_eval", "chunk_size"):
        if getattr(args, k) is not None:
            overrides[k] = getattr(args, k)
    cfg = config_for(args.preset, distribution=args.distribution, labels=label_kw, **overrides)
    out = dataset_dir(DEFAULT_CACHE, cfg) if args.out is None else args.out
    # a dataset of ours is resumed (finished splits are kept); anything else is refused
    fileio.check_output_dir(out, ours=is_dataset_dir, resume=True)
    print(XLA_CONFIG.summary(), file=sys.stderr)
    had = [n for n in args.splits if has_split(out, n)]  # kept, not made
    t0 = time.perf_counter()
    data = generate_dataset(cfg, out, splits=args.splits)
    dt = time.perf_counter() - t0
    for name, s in data.items():
        r = s.meta["reachability"]
        print(
            f"{name:>16s}: {len(s):>7d} trajectories, {s.scene_goals.shape[0]:>3d} scenes, "
            f"trajectory rejection {r['trajectory_rejection_rate']:.2%}, "
            f"scene rejection {r['scenes']['rejection_rate']:.2%}"
        )
    if len(had) == len(args.splits):
        print(f"found {out}: every split was already there (config digest {cfg.digest()})")
    else:
        kept = f", {len(had)} split(s) already there" if had else ""
        print(f"wrote {out} in {dt:.1f} s{kept} (config digest {cfg.digest()})")
    if out == preset_dir(args.preset):
        print(f"other commands find it as --data {args.preset} (in Python: "
              f'load_split("{args.preset}", ...))')  # fmt: skip
    return 0


def _relabel(args, label_kw: dict) -> int:
    """``--relabel``: new labels for the splits of ``--data`` (default: ``--out``) in ``--out``."""
    if args.out is None:
        raise cli.InputError("--relabel: give --out, the folder the relabelled splits go to")
    src = find_dataset(args.data) if args.data is not None else args.out
    if not is_dataset_dir(src):
        what = "--out" if args.data is None else "--data"
        raise cli.InputError(f"{what} {src}: holds no dataset splits to --relabel")
    in_place = args.out.exists() and args.out.resolve() == Path(src).resolve()
    held = [n for n in SPLITS if (Path(src) / f"{n}.json").is_file()]
    missing = [n for n in args.splits if n not in held]
    if missing:
        raise cli.InputError(
            f"{src}: holds no split {', '.join(missing)} to relabel; it holds {', '.join(held)} "
            "(choose them with --splits)"
        )
    cfg = _config_from_json(_read_json(Path(src) / f"{held[0]}.json")["config"])
    new = dataclasses.replace(cfg, labels=dataclasses.replace(cfg.labels, **label_kw))
    if in_place and Path(src).name == f"{cfg.preset}-{cfg.digest()}":
        raise cli.InputError(
            f"--out {args.out}: a cached dataset (<preset>-<digest>) that the main job reuses "
            "and other commands read; relabelled in place it would no longer be what its name "
            f"says: write the new labels to another folder, e.g. --data {args.out} --out "
            "data/relabelled"
        )
    fileio.check_output_dir(args.out, ours=is_dataset_dir, resume=True)
    if not in_place and args.out.exists():
        _check_dir_config(args.out, new)  # only an earlier relabelling of the same kind
    print(XLA_CONFIG.summary(), file=sys.stderr)
    for name in args.splits:
        if not in_place and (args.out / f"{name}.json").is_file():  # resumed: relabelled
            load_split(args.out, name)  # whole (its checksum holds), of this config (above)
            print(f"{name}: already relabelled in {args.out}, kept")
            continue
        split = load_split(src, name)
        meta = {k: v for k, v in split.meta.items() if k in ("reachability", "timing_s")}
        split = relabel(dataclasses.replace(split, meta=meta), new.labels)
        args.out.mkdir(parents=True, exist_ok=True)
        save_split(args.out, split, new)
        print(f"{name}: relabelled with {dataclasses.asdict(new.labels)}")
    print(f"wrote {args.out} (config digest {new.digest()})")
    return 0
