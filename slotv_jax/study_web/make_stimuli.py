"""Render stimulus sets with :mod:`slotv_jax.render`: ``python -m slotv_jax.study stimuli``.

The set's layout is documented in :mod:`slotv_jax.study.stimuli`. This module draws the
clips through MuJoCo (it needs OpenGL: ``MUJOCO_GL=egl`` on a headless machine), so the
study server, which only reads sets, never imports it.

``python -m slotv_jax.study stimuli --data DIR --split NAME --n N --taus 0.4,0.7,1.0
--out STIMDIR`` draws N motions of a dataset split at random (``--seed``), each at every
τ from every ``--cameras`` view, plus ``--attention`` more motions as attention checks
(τ = 1) and one practice motion; ``--size WxH``, ``--fps``, ``--duration`` (seconds of
a whole motion) and ``--hold`` (seconds the last frame stays) shape the clips.

>>> r = SceneRenderer(size=(320, 180), fps=20)                         # doctest: +SKIP
>>> write_stimulus_set("stim", q=q, xyz=xyz, goals=goals, goal_mask=mask, ids=ids,
...                    specs=cross_specs(range(3), taus=(0.5, 1.0), cameras=("observer",)),
...                    render=r)                                       # doctest: +SKIP
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from jaxtyping import Float, UInt8

from slotv_jax import render  # first: it picks MUJOCO_GL=egl before MuJoCo loads
from slotv_jax.data import SPLITS, Split, load_split
from slotv_jax.fileio import check_output_dir
from slotv_jax.render.overlay import LABEL_LIFT
from slotv_jax.study_web.stimuli import (
    MANIFEST,
    Motion,
    cross_specs,
    write_stimulus_set,
)

DEFAULTS = {"size": (480, 270), "fps": 25.0, "duration": 3.0, "hold": 0.5}


class SceneRenderer:
    """:class:`slotv_jax.study.stimuli.Renderer` on MuJoCo (one renderer, reused)."""

    def __init__(
        self,
        size: tuple[int, int] = DEFAULTS["size"],
        fps: float = DEFAULTS["fps"],
        duration: float = DEFAULTS["duration"],
        hold: float = DEFAULTS["hold"],
        *,
        trace: bool = True,
    ):
        self.size, self.fps, self.duration, self.hold = tuple(size), fps, duration, hold
        self.trace = trace
        self.renderer = render.MotionRenderer(self.size)

    def frames(
        self, motion: Motion, tau: float, camera: str
    ) -> tuple[UInt8[np.ndarray, "F H W 3"], Float[np.ndarray, "G 2"]]:
        """The clip cut at τ, goals labelled (no target marked), and the labels' pixels."""
        f = render.motion_frames(
            motion.q, motion.goals, motion.goal_mask, camera=camera, tau=tau, size=self.size,
            fps=self.fps, duration=self.duration, hold=self.hold, t=motion.t,
            labels=motion.labels, trace=self.trace, renderer=self.renderer,
        )  # fmt: skip
        anchor = np.asarray(motion.goals, np.float64)[motion.goal_mask] + [0.0, 0.0, LABEL_LIFT]
        px, _ = render.pixels(anchor, camera, self.size)
        return f, px

    def write_video(self, path: Path, frames) -> None:
        render.write_video(path, frames, self.fps)

    def write_image(self, path: Path, image) -> None:
        render.write_png(path, image)

    def settings(self) -> dict:
        return {"size": list(self.size), "fps": self.fps, "duration": self.duration,
                "hold": self.hold}  # fmt: skip

    def close(self) -> None:
        self.renderer.close()


def from_split(
    split: Split,
    out: str | Path,
    *,
    n: int,
    taus: tuple[float, ...],
    cameras: tuple[str, ...] = ("observer",),
    attention: int = 2,
    practice: bool = True,
    seed: int = 0,
    renderer: SceneRenderer,
    overwrite: bool = False,
    progress: bool = True,
    source: dict | None = None,
) -> dict:
    """A stimulus set of ``n`` motions of a dataset split drawn at random (see the module).

    Trajectory ids are ``SPLIT-INDEX``, scenes ``SPLIT-sceneENV``. Returns the manifest.
    """
    need = n + attention + int(practice)
    if not 1 <= n or need > len(split):
        raise ValueError(
            f"--n {n}: expected 1 <= n and n + attention + practice <= {len(split)} "
            f"(the motions of split {split.name!r})"
        )
    pick = np.random.default_rng(seed).permutation(len(split))[:need]
    ids = [f"{split.name}-{i}" for i in pick]
    specs = cross_specs(
        range(n), taus=taus, cameras=cameras,
        attention=range(n, n + attention), practice=[need - 1] if practice else [],
    )  # fmt: skip
    src = {"kind": "split", "split": split.name, "indices": pick.tolist(), "seed": seed,
           **(source or {})}  # fmt: skip
    return write_stimulus_set(
        out, q=split.q[pick], xyz=split.xyz[pick], goals=split.goals[pick],
        goal_mask=split.goal_mask[pick], ids=ids, specs=specs, render=renderer,
        scenes=[f"{split.name}-scene{e}" for e in split.env_id[pick]],
        targets=split.target[pick], source=src, overwrite=overwrite, progress=progress,
    )  # fmt: skip


def _floats(text: str, name: str) -> tuple[float, ...]:
    try:
        vals = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise ValueError(f"{name} {text}: expected comma-separated numbers") from None
    if not vals or any(not 0.0 < v <= 1.0 for v in vals) or len(set(vals)) != len(vals):
        raise ValueError(f"{name} {text}: expected distinct normalised times in (0, 1]")
    return vals


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ValueError(f"--size {text}: expected WIDTHxHEIGHT, e.g. 480x270") from None
    if not (16 <= w <= 4096 and 16 <= h <= 4096) or w % 2 or h % 2:
        raise ValueError(f"--size {text}: expected even sides in 16..4096 (H.264)")
    return w, h


def add_command(sub) -> None:
    """Add ``stimuli`` to the study CLI's subparsers."""
    p = sub.add_parser("stimuli", help="render a stimulus set (clips cut at tau, stills)")
    p.add_argument("--data", required=True, help="dataset folder (python -m slotv_jax.data)")
    p.add_argument("--split", default="trajectory_test", choices=SPLITS)
    p.add_argument("--n", type=int, default=10, help="motions shown at every tau")
    p.add_argument("--taus", default="0.4,0.7,1.0", help="stop times in (0, 1]")
    p.add_argument("--cameras", default="observer", help=f"comma-separated: {render.CAMERAS}")
    p.add_argument("--attention", type=int, default=2, help="attention-check motions (tau 1)")
    p.add_argument("--no-practice", action="store_true", help="no practice trial")
    p.add_argument("--size", default="480x270", help="WIDTHxHEIGHT of the clips")
    p.add_argument("--fps", type=float, default=DEFAULTS["fps"])
    p.add_argument("--duration", type=float, default=DEFAULTS["duration"],
                   help="seconds of a whole motion (tau = 1)")  # fmt: skip
    p.add_argument("--hold", type=float, default=DEFAULTS["hold"],
                   help="seconds the last frame stays")  # fmt: skip
    p.add_argument("--no-trace", action="store_true", help="do not draw the TCP's path")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", required=True, help="the study folder to write")
    p.add_argument("--overwrite", action="store_true", help="replace an earlier set there")


def stimuli_main(args: argparse.Namespace) -> int:
    """Check every input and the output folder, then render the set."""
    taus = _floats(args.taus, "--taus")
    size = _size(args.size)
    cameras = tuple(c.strip() for c in args.cameras.split(","))
    for c in cameras:
        if c not in render.CAMERAS:
            raise ValueError(f"--cameras {args.cameras}: {c!r} is not one of {render.CAMERAS}")
    if args.attention < 0:
        raise ValueError(f"--attention {args.attention}: expected an integer >= 0")
    for name in ("fps", "duration"):
        if not getattr(args, name) > 0:
            raise ValueError(f"--{name} {getattr(args, name)}: expected a number > 0")
    if not args.hold >= 0:
        raise ValueError(f"--hold {args.hold}: expected seconds >= 0")
    check_output_dir(args.out, ours=lambda p: (p / MANIFEST).is_file(), overwrite=args.overwrite)
    split = load_split(args.data, args.split)
    try:
        r = SceneRenderer(size, args.fps, args.duration, args.hold, trace=not args.no_trace)
    except render.RenderBackendError as e:
        raise ValueError(str(e)) from None  # one line: how to get OpenGL
    try:
        m = from_split(
            split, args.out, n=args.n, taus=taus, cameras=cameras, attention=args.attention,
            practice=not args.no_practice, seed=args.seed, renderer=r,
            overwrite=args.overwrite, source={"data": str(args.data)},
        )  # fmt: skip
    finally:
        r.close()
    print(f"wrote {args.out}: {len(m['stimuli'])} stimuli ({args.out}/{MANIFEST})")
    return 0
