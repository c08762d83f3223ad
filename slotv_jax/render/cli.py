"""``python -m slotv_jax.render``: render trajectories as MP4, GIF or PNG
(:ref:`concepts-commands`).

Sources (one of):

- ``--data DIR --split NAME --index I``: a dataset split (``slotv_jax.data``); ``DIR`` a
  folder or a preset name (``quick``: the dataset the main job made, in ``data/quick-<digest>``);
- ``--npz FILE --index I``: the labelers CLI's input format (``xyz (N, T, 3)``,
  ``goals``, ``goal_mask``, optional ``t`` and ``q (N, T, 7)``);
- ``--study FILE --index I``: a study file (:func:`slotv_jax.study.load_study`), its
  goal names available as labels (``--labels names``);
- ``--plans FILE --problem I [--planner NAME[,NAME...]]``: a planning run's ``plans.npz``
  (``goals (P, 8, 3)``, ``goal_mask (P, 8)``, ``target (P,)``, ``family (P,)``,
  ``names (K,)`` planner names, ``q (K, P, T, 7)``, ``xyz (K, P, T, 3)``); without
  ``--planner`` every planner side by side (``--layout overlay``: in one scene), with
  several names those side by side. ``--grid`` puts the chosen problems (default: three,
  the families in turn) into one ``.png``, a captioned row of panels each, every planner
  whose plans are finite in all of them (the planning experiment's figure).

``--timed`` plays the motion at the speed a Franka arm would make it
(:func:`slotv_jax.execution.time_plan`: its published limits times ``--speed``), instead of
``--duration`` seconds for the whole motion: the clip lasts as long as the robot's motion, each
frame shows the robot where it is at that moment, and ``--tau`` is a fraction of that
duration. One motion per clip (``--plans`` with one ``--planner``).

A TCP path without joints (``--npz`` without ``q``, ``--study``) goes through the
project's inverse kinematics (:func:`slotv_jax.kinematics.solve_path_ik`, from
``Q_HOME``) first. ``--index`` (and ``--problem``) take ``I``, ``A:B`` or ``I,J,K``;
several items go into ``--out DIR`` as ``<source>_<i>.<--format>``, through one renderer,
with a progress bar. One item goes to ``--out FILE``, whose suffix picks the format:
``.mp4`` (H.264), ``.gif``, or ``.png`` (the last frame; ``--sheet N``: N frames in a
grid). Everything is checked before any rendering: an input error prints one line
``error: ...`` and exits with 2.

A clip is bounded (:func:`slotv_jax.rendering.frames.check_clip`; every frame is held in
memory before it is encoded): ``--fps`` at most ``MAX_FPS`` (240), at most
``MAX_CLIP_FRAMES`` frames (18000: 10 minutes at 30 fps, the motion and ``--hold``), and at
most ``MAX_CLIP_BYTES`` of frames (4 GiB: ``W × H × 3`` bytes a frame, every panel's side
by side), checked before anything is loaded (a ``--timed`` clip's length once its motion
is timed).

    python -m slotv_jax.render --data quick --split position_test --index 0 --out a.mp4
    python -m slotv_jax.render --plans plans.npz --problem 3 --tau 0.5 --out compare.png
    python -m slotv_jax.render --plans plans.npz --problem 3 --planner slotv --timed --out slotv.mp4
    python -m slotv_jax.render --plans plans.npz --grid --planner straight,oracle,slotv \
        --camera observer_angle --tau 0.6 --size 480x270 --out figure.png
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from slotv_jax.answers.storage import load_study
from slotv_jax.core import cli, fileio
from slotv_jax.data import SPLITS, load_split
from slotv_jax.execution import Refused, TimingConfig, time_plan
from slotv_jax.execution.cli import add_timing_args, timing_from_args
from slotv_jax.planning.plans import load_plans
from slotv_jax.rendering.camera import CAMERAS, FreeCamera
from slotv_jax.rendering.compare import GAP, LAYOUTS, PALETTE, compare_frames
from slotv_jax.rendering.frames import (
    CLIP_BOUNDS,
    MAX_FPS,
    MotionRenderer,
    RenderBackendError,
    check_clip,
    check_motion,
    check_size,
    check_timing,
    joints_from_tcp,
    motion_frames,
)
from slotv_jax.rendering.overlay import title
from slotv_jax.rendering.writers import (
    SUFFIXES,
    check_output,
    contact_sheet,
    write_png,
    write_video,
)
from slotv_jax.robot import kinematics
from slotv_jax.world import scene

IK_WARN = 5e-3  # metres: a TCP path the IK misses by more is reported
LABEL_CHOICES = ("letters", "names", "none")


@dataclasses.dataclass(frozen=True)
class Item:
    """One picture or clip to render: one motion, or several compared."""

    key: str  # names the output file: <key>.<format>
    qs: tuple[np.ndarray, ...]  # (T, 7) joint paths, one per motion
    goals: np.ndarray  # (8, 3)
    goal_mask: np.ndarray  # (8,)
    target: int  # the target goal slot
    t: np.ndarray | None = None  # (T,) sample times of a single motion
    names: tuple[str, ...] = ()  # motion names (compared planners)
    rgbas: tuple[tuple, ...] | None = None  # their trace colours
    goal_names: tuple[str, ...] = ()  # labels of the real goals, where the source has them
    caption: str = ""  # a --grid row's caption
    duration: float | None = None  # seconds of the whole motion (--timed: the robot's)


def parse_indices(text: str, n: int, what: str) -> list[int]:
    """``I``, ``A:B`` (B excluded) or ``I,J,K`` → indices, each in 0..n−1."""
    try:
        if ":" in text:
            a, b = text.split(":")
            idx = list(range(int(a or 0), int(b) if b else n))
        else:
            idx = [int(v) for v in text.split(",")]
    except ValueError:
        raise cli.InputError(f"{what}: expected I, A:B or I,J,K, got {text!r}") from None
    if not idx or any(not 0 <= i < n for i in idx):
        raise cli.InputError(f"{what} {text}: expected indices in 0..{n - 1}")
    return idx


def parse_size(text: str) -> tuple[int, int]:
    """``WxH`` → (W, H)."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
        return check_size((w, h))
    except ValueError:
        raise cli.InputError(f"--size: expected WxH in 16..4096 pixels, got {text!r}") from None


def _ik(xyz: np.ndarray, what: str) -> np.ndarray:
    """Joint path of a TCP path (warm-started IK from Q_HOME); warns on a large miss."""
    q, worst = joints_from_tcp(xyz)
    if worst > IK_WARN:
        print(f"warning: {what}: IK misses the path by up to {worst * 1e3:.1f} mm", file=sys.stderr)
    return q


def _data_items(args) -> list[Item]:
    if args.split not in SPLITS:
        raise cli.InputError(f"--split: expected one of {list(SPLITS)}, got {args.split!r}")
    sp = load_split(args.data, args.split)
    idx = parse_indices(args.index or "0", len(sp), "--index")
    return [
        Item(f"{args.split}_{i:04d}", (sp.q[i],), sp.goals[i], sp.goal_mask[i], int(sp.target[i]))
        for i in idx
    ]


def _npz_items(args) -> list[Item]:
    z = fileio.load_npz(args.npz)
    for k in ("xyz", "goals", "goal_mask"):
        if k not in z:
            raise cli.InputError(f"--npz {args.npz}: missing array {k!r}; it holds {sorted(z)}")
    xyz = z["xyz"]
    if xyz.ndim != 3 or xyz.shape[-1] != 3:
        raise cli.InputError(f"--npz {args.npz}: xyz: expected (N, T, 3), got {xyz.shape}")
    n = xyz.shape[0]
    idx = parse_indices(args.index or "0", n, "--index")
    goals, mask = z["goals"], z["goal_mask"]
    target = z.get("target")
    items = []
    for i in idx:
        g = goals[i] if goals.ndim == 3 else goals
        m = mask[i] if mask.ndim == 2 else mask
        t = None if "t" not in z else (z["t"][i] if z["t"].ndim == 2 else z["t"])
        q = z["q"][i] if "q" in z else None
        if q is None:
            try:
                check_motion(np.zeros((xyz.shape[1], 7)), g, m, t=t)
                kinematics.check_ik_inputs(xyz[i], kinematics.Q_HOME)
            except ValueError as e:
                raise cli.InputError(f"--npz {args.npz} [{i}]: {e}") from None
            q = _ik(xyz[i], f"--npz {args.npz} [{i}]")
        tgt = -1 if target is None else int(np.ravel(target)[i if np.size(target) > 1 else 0])
        items.append(Item(f"{Path(args.npz).stem}_{i:04d}", (q,), g, m, tgt, t=t))
    return items


def _study_items(args) -> list[Item]:
    st = load_study(args.study)
    idx = parse_indices(args.index or "0", st.n_trajectories, "--index")
    items = []
    for i in idx:
        n = int(st.length[i])
        t = None if st.t is None else st.t[i, :n]
        names = ()
        if st.goal_names is not None:
            names = tuple(str(s) for s in st.goal_names[i][st.goal_mask[i]])
        q = _ik(st.xyz[i, :n], f"--study {args.study} [{i}]")
        key = st.trajectory_ids[i] if st.trajectory_ids else f"{i:04d}"
        items.append(
            Item(f"study_{key}", (q,), st.goals[i], st.goal_mask[i], -1, t=t, goal_names=names)
        )
    return items


def _plan_title(z: dict, names: list[str], k: int, p: int) -> str:
    """A planner's name, with the target's probability under the family's labeler
    (``y``, where the plans file has it)."""
    if "y" not in z:
        return names[k]
    return f"{names[k]}: P = {z['y'][k, p, int(z['target'][p])]:.2f}"


def grid_problems(family: np.ndarray, n: int = 3) -> list[int]:
    """``n`` problems taking the families in turn (in order of appearance), row r its
    r-th problem: different scenes when the families share their problems' order."""
    fams = list(dict.fromkeys(str(f) for f in family))
    rows = {f: [i for i, g in enumerate(family) if str(g) == f] for f in fams}
    out = []
    for r in range(n):
        idx = rows[fams[r % len(fams)]]
        if r < len(idx) and idx[r] not in out:
            out.append(idx[r])
    return out


def _plans_items(args) -> list[Item]:
    z = load_plans(args.plans)
    q, names = z["q"], [str(s) for s in z["names"]]
    family = z.get("family")
    if args.problem is None and args.grid:
        idx = grid_problems(np.zeros(q.shape[1], str) if family is None else family)
    else:
        idx = parse_indices(args.problem or "0", q.shape[1], "--problem")
    ks = list(range(len(names)))
    if args.planner is not None:
        wanted = [w.strip() for w in args.planner.split(",")]
        unknown = [w for w in wanted if w not in names]
        if unknown:
            raise cli.InputError(f"--planner: expected names among {names}, got {unknown}")
        ks = [names.index(w) for w in wanted]
    stem = Path(args.plans).stem
    suffix = f"_{args.planner.replace(',', '_')}" if args.planner else ""
    if args.grid:  # the same panels in every row: planners finite in all the problems
        ks = [k for k in ks if args.planner or np.isfinite(q[k, idx]).all()]
        if not ks:
            raise cli.InputError(
                f"--plans {args.plans}: q: no planner has a plan of every problem of the grid "
                f"({', '.join(map(str, idx))}); choose others with --problem"
            )
    items = []
    for p in idx:
        shown = [k for k in ks if args.planner or np.isfinite(q[k, p]).all()]  # NaN: left out
        if not shown:
            raise cli.InputError(
                f"--plans {args.plans}: q: no planner has a plan of problem {p} (each row "
                "holds NaN); choose another --problem"
            )
        if len(shown) > len(PALETTE):
            raise cli.InputError(
                f"--plans {args.plans}: names: {len(shown)} planners of problem {p}, at most "
                f"{len(PALETTE)} side by side; name at most {len(PALETTE)} with --planner"
            )
        fam = "" if family is None else f" ({family[p]})"
        cube = chr(ord("A") + int(z["target"][p]))
        items.append(
            Item(
                f"{stem}_{p:04d}{suffix}",
                tuple(q[k, p] for k in shown),
                z["goals"][p],
                z["goal_mask"][p],
                int(z["target"][p]),
                names=tuple(_plan_title(z, names, k, p) for k in shown),
                rgbas=tuple(PALETTE[k % len(PALETTE)] for k in shown),
                caption=f"problem {p}{fam}: to cube {cube}, seen up to τ = {args.tau:g}",
            )
        )
    return items


def _parser() -> argparse.ArgumentParser:
    p = cli.ArgumentParser(
        prog="python -m slotv_jax.render",
        description="Render trajectories of the Panda in its scene as MP4, GIF or PNG "
        "(needs OpenGL: MUJOCO_GL=egl on a headless machine).",
        epilog=CLIP_BOUNDS,
    )
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument(
        "--data",
        type=Path,
        help="dataset folder, or a preset name (quick, paper) for the main job's (with --split)",
    )
    src.add_argument("--npz", type=Path, help="a .npz in the labelers CLI's input format")
    src.add_argument("--study", type=Path, help="a study file (slotv_jax.study)")
    src.add_argument("--plans", type=Path, help="a planning run's plans.npz")
    p.add_argument("--split", help="dataset split name (with --data)")
    p.add_argument("--index", help="trajectory: I, A:B or I,J,K (default 0)")
    p.add_argument("--problem", help="planning problem: I, A:B or I,J,K (with --plans)")
    p.add_argument("--planner", help="planner(s) of --plans, NAME[,NAME] (default: all)")
    p.add_argument("--layout", default="side", choices=LAYOUTS, help="how planners are compared")
    p.add_argument(
        "--grid",
        action="store_true",
        help="with --plans and a .png --out: the problems as captioned rows of one picture "
        "(default --problem: three, the families in turn)",
    )
    p.add_argument("--tau", type=float, default=1.0, help="show the motion up to τ in (0, 1]")
    p.add_argument(
        "--camera", default="observer",
        help=f"{', '.join(CAMERAS)}, free, or a camera file (*.json: the lab's camera)",
    )  # fmt: skip
    for f, d in (("lookat", "0.45,0,0.15"), ("distance", "1.6")):
        p.add_argument(f"--{f}", default=d, help=f"free camera {f} (default {d})")
    p.add_argument("--azimuth", type=float, default=180.0, help="free camera azimuth (deg)")
    p.add_argument("--elevation", type=float, default=-30.0, help="free camera elevation (deg)")
    p.add_argument("--size", default="640x360", help="frame size WxH (default 640x360)")
    p.add_argument(
        "--fps",
        type=float,
        default=30.0,
        help=f"frames per second (default 30, at most {MAX_FPS:g})",
    )
    p.add_argument("--duration", type=float, default=None,
                   help="seconds of the whole motion (default 3)")  # fmt: skip
    add_timing_args(p, instead="--duration seconds")
    p.add_argument("--hold", type=float, default=1.0, help="seconds the last frame is held")
    p.add_argument("--labels", default="letters", choices=LABEL_CHOICES, help="goal labels")
    p.add_argument(
        "--mark-target", action="store_true", help="draw a disc under the target (--plans: always)"
    )
    p.add_argument("--no-trace", action="store_true", help="do not draw the TCP's path")
    p.add_argument("--shadows", action="store_true", help="render shadows (slower on a CPU)")
    p.add_argument("--sheet", type=int, help="with a .png: N frames in a grid, not the last")
    p.add_argument("--out", required=True, type=Path, help="output file, or folder for several")
    p.add_argument("--format", default="mp4", choices=[s[1:] for s in SUFFIXES])
    p.add_argument("--overwrite", action="store_true", help="replace existing output files")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    return p


def _camera(args):
    if args.camera == "free":
        try:
            lookat = tuple(float(v) for v in args.lookat.split(","))
            return FreeCamera(lookat, float(args.distance), args.azimuth, args.elevation)
        except ValueError as e:
            raise cli.InputError(f"--camera free: {e}") from None
    if scene.is_camera_file(args.camera):
        try:
            scene.check_camera(args.camera)
        except ValueError as e:
            raise cli.InputError(f"--camera: {e}") from None
        return args.camera
    if args.camera not in CAMERAS:
        raise cli.InputError(
            f"--camera: expected one of {[*CAMERAS, 'free']} or a camera file (*.json), "
            f"got {args.camera!r}"
        )
    return args.camera


def _labels(args, item: Item):
    if args.labels == "names":
        if not item.goal_names:
            raise cli.InputError(
                f"--labels names: {item.key} has no goal names (only a --study file has them); "
                "use --labels letters"
            )
        return list(item.goal_names)
    return None


def _outputs(args, items: list[Item]) -> list[Path]:
    """The output file of every item, checked (output rule) before any rendering."""
    single = (len(items) == 1 or args.grid) and args.out.suffix != ""
    if single:
        paths = [args.out]
    else:
        if args.out.suffix:
            raise cli.InputError(
                f"--out {args.out}: {len(items)} items need a folder (and --format), not a file"
            )
        paths = [args.out / f"{it.key}.{args.format}" for it in items]
    inputs = {f"--{k}": getattr(args, k) for k in ("data", "npz", "study", "plans")}
    for path in paths:
        fileio.check_not_input(path, inputs)
        check_output(path, overwrite=args.overwrite)
    if args.sheet is not None and (args.sheet < 1 or any(p.suffix != ".png" for p in paths)):
        raise cli.InputError("--sheet: expected N >= 1 with a .png output")
    return paths


@cli.command
def main(argv: Sequence[str] | None = None) -> int:
    """Parse, load and check everything, then render and write each item."""
    args = _parser().parse_args(argv)
    if (args.data is None) != (args.split is None):
        raise cli.InputError("--data and --split: expected both or neither")
    if args.plans is None and (args.problem or args.planner or args.grid):
        raise cli.InputError("--problem, --planner and --grid: only with --plans")
    if args.grid and (args.out.suffix.lower() != ".png" or args.sheet is not None):
        raise cli.InputError(f"--grid: expected a .png --out and no --sheet, got {args.out}")
    size = parse_size(args.size)
    if args.timed and args.duration is not None:
        raise cli.InputError("--duration: --timed plays the motion at the robot's own speed; "
                             "leave --duration out")  # fmt: skip
    if args.timed and args.grid:
        raise cli.InputError("--timed: a --grid shows stills; leave --timed out")
    args.duration = 3.0 if args.duration is None else args.duration
    check_timing(args.tau, args.fps, args.duration, args.hold)
    # before any loading: the clip within its bounds (a --timed one's length comes later)
    check_clip(size, fps=args.fps, duration=None if args.timed else args.duration,
               hold=args.hold, tau=args.tau, prefix="--")  # fmt: skip
    timing = timing_from_args(args)
    camera = _camera(args)
    load = {"data": _data_items, "npz": _npz_items, "study": _study_items, "plans": _plans_items}
    items = next(f(args) for k, f in load.items() if getattr(args, k) is not None)
    paths = _outputs(args, items)
    if scene.is_camera_file(camera):  # it films what it shows
        try:
            scene.check_sees_goals(camera, np.stack([it.goals for it in items]),
                                   np.stack([it.goal_mask for it in items]))  # fmt: skip
        except ValueError as e:
            raise cli.InputError(f"--camera: {e}") from None
    if timing is not None:  # before any rendering: every motion timed, or one line why not
        items = [_timed(it, timing) for it in items]
    if not args.grid:  # every clip within its bounds: its panels, a timed motion's length
        for it in items:
            _check_clip(args, size, it, timing)
    for it in items:
        for q in it.qs:
            try:
                check_motion(q, it.goals, it.goal_mask, t=it.t, labels=_labels(args, it))
            except ValueError as e:
                raise cli.InputError(f"{it.key}: {e}") from None
    kw = {
        "camera": camera,
        "tau": args.tau,
        "size": size,
        "fps": args.fps,
        "duration": args.duration,
        "hold": args.hold,
        "trace": not args.no_trace,
    }
    try:
        renderer = MotionRenderer(size, shadows=args.shadows)
    except RenderBackendError as e:
        raise cli.InputError(str(e)) from None
    with renderer:
        if args.grid:  # each row: the last frame at τ, under its caption
            still = {**kw, "fps": 1.0 / args.tau, "duration": 1.0, "hold": 0.0}
            rows = []
            for it in tqdm(items, disable=args.quiet, unit="row"):
                last = _frames(args, it, **still, target=it.target, renderer=renderer,
                               cols=len(it.qs))[-1]  # fmt: skip
                rows.append(np.concatenate([title(last, it.caption), last]))
            gap = np.full((GAP, rows[0].shape[1], 3), 255, np.uint8)
            write_png(paths[0], np.concatenate([x for r in rows for x in (r, gap)][:-1]))
            print(f"wrote {paths[0]} ({len(items)} problems x {len(items[0].qs)} planners)")
            return 0
        for it, path in tqdm(list(zip(items, paths, strict=True)), disable=args.quiet, unit="clip"):
            # plans are of a target: marked always (a planner's name says nothing of it)
            marked = args.mark_target or args.plans is not None
            target = it.target if marked and it.target >= 0 else None
            frames = _frames(args, it, **kw, target=target, renderer=renderer)
            if path.suffix == ".png" and args.sheet:
                write_png(path, contact_sheet(frames, args.sheet, cols=min(args.sheet, 4)))
            else:
                path.parent.mkdir(parents=True, exist_ok=True)
                write_video(path, frames, args.fps)
    print(f"wrote {len(paths)} file(s): {paths[0]}{' ...' if len(paths) > 1 else ''}")
    return 0


def _timed(it: Item, timing: TimingConfig) -> Item:
    """``it`` at the robot's speed: its configurations at the times the robot passes them
    (:func:`slotv_jax.execution.time_plan`), the clip as long as the motion."""
    if len(it.qs) != 1:
        raise cli.InputError(f"--timed: {it.key} compares {len(it.qs)} motions; a timed clip "
                             "shows one (choose it with --planner NAME)")  # fmt: skip
    try:
        traj = time_plan(it.qs[0], timing)
    except (ValueError, Refused) as e:
        raise cli.InputError(f"--timed: {it.key}: {e}") from None
    return dataclasses.replace(it, qs=(traj.path.plan_q,), t=traj.knot_times,
                               duration=traj.duration)  # fmt: skip


def _check_clip(args, size: tuple[int, int], it: Item, timing: TimingConfig | None) -> None:
    """``it``'s clip within the bounds of :func:`slotv_jax.rendering.frames.check_clip`."""
    panels = len(it.qs) if args.layout == "side" else 1
    if it.duration is None:
        check_clip(size, fps=args.fps, duration=args.duration, hold=args.hold, tau=args.tau,
                   panels=panels, prefix="--")  # fmt: skip
        return
    try:
        check_clip(size, fps=args.fps, duration=it.duration, hold=args.hold, tau=args.tau,
                   panels=panels)  # fmt: skip
    except ValueError as e:
        raise cli.InputError(f"--timed: {it.key} lasts {it.duration:.4g} s at --speed "
                             f"{timing.speed:g}: {e}") from None  # fmt: skip


def _frames(args, it: Item, **kw) -> np.ndarray:
    """Every frame of one item: its motion, or its motions compared (``--layout``)."""
    if it.duration is not None:
        kw["duration"] = it.duration
    kw |= {"labels": _labels(args, it), "show_labels": args.labels != "none"}
    if len(it.qs) == 1 and not it.names:
        kw.pop("cols", None)  # a --grid row of one motion: one panel anyway
        return motion_frames(it.qs[0], it.goals, it.goal_mask, t=it.t, **kw)
    ts = None if it.t is None else [it.t]  # a timed plan: one motion, its own times
    return compare_frames(it.qs, it.goals, it.goal_mask, names=it.names, rgbas=it.rgbas, ts=ts,
                          layout=args.layout, **kw)  # fmt: skip
