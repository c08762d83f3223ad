"""The command line of the labelers: ``python -m slotv_jax.labelers --in trajs.npz --out
labels.npz``.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from slotv_jax.core import cli, fileio
from slotv_jax.core.fileio import atomic_write
from slotv_jax.core.xla import XLA_CONFIG
from slotv_jax.observers.labelers import DEFAULT_BETAS, LABELER_NAMES
from slotv_jax.observers.labelling import label_all
from slotv_jax.world import scene

# ------------------------------------------------------------------ command line


def _savez(path, arrays: dict[str, np.ndarray]) -> None:
    atomic_write(path, lambda f: np.savez(f, **arrays))


@cli.command
def main(argv: Sequence[str] | None = None) -> int:
    """``python -m slotv_jax.labelers --in trajs.npz --out labels.npz [--overwrite]``."""

    p = cli.ArgumentParser(
        prog="python -m slotv_jax.labelers",
        description="Label trajectories with the four legibility labelers (concepts: labelers). "
        "The input "
        ".npz holds xyz (N, T, 3), goals (N, 8, 3) or (8, 3), goal_mask (N, 8) or (8,), and "
        "optionally t (T,) or (N, T); the output .npz holds y_<labeler> (N, 8) float32 and the "
        "betas used.",
    )
    p.add_argument("--in", dest="inp", required=True, type=Path, help="input .npz")
    p.add_argument("--out", required=True, type=Path, help="output .npz (written atomically)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    for n in LABELER_NAMES:
        p.add_argument(f"--beta-{n}", type=float, default=DEFAULT_BETAS[n], help=f"β of {n}")
    p.add_argument(
        "--camera", default="observer",
        help="the camera for nikolaidis: a camera of the scene or a camera file (*.json)",
    )  # fmt: skip
    p.add_argument(
        "--labelers", default=",".join(LABELER_NAMES), help="comma-separated subset to compute"
    )
    p.add_argument(
        "--chunk-size", type=int, help="trajectories per chunk (default: 16384 / labelers)"
    )
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    args = p.parse_args(argv)
    fileio.check_not_input(args.out, {"--in": args.inp})
    fileio.check_output_file(args.out, overwrite=args.overwrite, suffix=".npz")
    try:
        scene.check_camera(args.camera)
    except ValueError as e:
        raise cli.InputError(f"--camera: {e}") from None
    print(XLA_CONFIG.summary(), file=sys.stderr)

    names = tuple(s.strip() for s in args.labelers.split(",") if s.strip())
    arrays = fileio.load_npz(args.inp)
    files = list(arrays)
    data = {k: arrays[k] for k in ("xyz", "goals", "goal_mask", "t") if k in files}
    missing = [k for k in ("xyz", "goals", "goal_mask") if k not in data]
    if missing:
        raise cli.InputError(f"--in {args.inp}: missing array(s) {missing}; it holds {files}")
    betas = {n: getattr(args, f"beta_{n}") for n in LABELER_NAMES}
    try:
        y = label_all(
            data["xyz"],
            data["goals"],
            data["goal_mask"],
            t=data.get("t"),
            chunk_size=args.chunk_size,
            progress=not args.quiet,
            labelers=names,
            camera=args.camera,
            **{f"beta_{n}": b for n, b in betas.items()},
        )
    except ValueError as e:
        raise cli.InputError(f"--in {args.inp}: {e}") from None
    arrays = {f"y_{n}": v for n, v in y.items()}
    arrays.update({f"beta_{n}": np.float64(betas[n]) for n in names})
    if "nikolaidis" in names:
        arrays["camera"] = np.asarray(args.camera)
    _savez(args.out, arrays)
    print(f"wrote {', '.join(arrays)} for {len(data['xyz'])} trajectories to {args.out}")
    return 0
