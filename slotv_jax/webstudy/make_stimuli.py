"""Render stimulus sets with :mod:`slotv_jax.rendering`: ``python -m slotv_jax.study stimuli``.

The set's layout is documented in :mod:`slotv_jax.webstudy.stimuli`. This module draws the
clips through MuJoCo (it needs OpenGL: ``MUJOCO_GL=egl`` on a headless machine), so the
study server, which only reads sets, never imports it.

``python -m slotv_jax.study stimuli --data DIR --split NAME --n N --taus 0.4,0.7,1.0
--out STIMDIR`` draws N motions of a source at random (``--seed``), each at every τ
from every ``--cameras`` view, plus ``--attention`` more motions as attention checks
(τ = 1) and one practice motion; ``--size WxH``, ``--fps``, ``--duration`` (seconds of
a whole motion) and ``--hold`` (seconds the last frame stays) shape the clips, each within
the bounds of :func:`slotv_jax.rendering.frames.check_clip` (``--fps`` at most 240, at most
18000 frames: 10 minutes at 30 fps, at most 4 GiB of frames; every frame of a clip is held in
memory before it is encoded), checked before anything is loaded. Sources:

- ``--data DIR --split NAME``: a dataset split (ids ``SPLIT-INDEX``);
- ``--plans FILE``: a planning run's ``plans.npz``, every planner's plan of every problem
  (ids ``PLANNER-PROBLEM``): people's guesses on the plans of each observer;
- ``--npz FILE``: trajectories in the labelers' format (``xyz``, ``goals``,
  ``goal_mask``, optional ``t``, ``q`` and ``target``);
- ``--study FILE``: a study file's trajectories (no targets: ``--attention 0``).

``--next-round STIMDIR`` (instead of ``--out``) adds the set to an existing study folder
as its next round (``STIMDIR/round-R``, as ``study next`` does): with round 0's clip
settings (``--size``, ``--fps``, ``--duration`` and ``--hold`` are then refused), and a
trajectory id that an earlier round holds must be the same motion there (ids are global
across rounds). A running server (``study serve``) gives the round to new participants
without a restart: the plans of a planning run become an evaluation round of the study
that taught their observer, e.g. ::

    python -m slotv_jax.study stimuli --plans plans.npz --n 6 --taus 0.4,1.0 \
        --next-round stim

``--timed`` shows each motion at the speed a Franka arm makes it (:mod:`slotv_jax.execution`:
its published limits times ``--speed``) instead of ``--duration`` seconds for every motion:
a clip stopped at τ ends τ of the way through the robot's motion, in time, and
``trajectories.csv`` holds each point's time as a fraction of that motion's duration, so
that what a participant saw up to τ is the points up to t = τ. The manifest's ``timing``
records it (``{"robot", "speed", "limits"}``; null: every motion ``duration`` seconds, its
points evenly in time), and ``study next`` draws later rounds the same way.

A TCP path without joints gets them by the project's IK from ``Q_HOME``
(:func:`slotv_jax.rendering.joints_from_tcp`); a path it misses by more than 5 mm is refused.

>>> r = SceneRenderer(size=(320, 180), fps=20)                         # doctest: +SKIP
>>> write_stimulus_set("stim", q=q, xyz=xyz, goals=goals, goal_mask=mask, ids=ids,
...                    specs=cross_specs(range(3), taus=(0.5, 1.0), cameras=("observer",)),
...                    render=r)                                       # doctest: +SKIP
"""

from __future__ import annotations

import argparse
import re
from collections.abc import Mapping
from pathlib import Path
from typing import NamedTuple

import numpy as np
from jaxtyping import Float, UInt8
from tqdm.auto import tqdm

from slotv_jax import rendering  # first: it picks MUJOCO_GL=egl before MuJoCo loads
from slotv_jax.answers.storage import load_study
from slotv_jax.core import validation
from slotv_jax.core.fileio import check_not_input, check_output_dir, load_npz
from slotv_jax.data import SPLITS, Split, load_split
from slotv_jax.execution import DEFAULT_SPEED, Refused, TimingConfig, time_plan
from slotv_jax.execution import models as execution_models
from slotv_jax.execution.cli import add_timing_args, timing_from_args
from slotv_jax.execution.limits import SOURCE, check_speed
from slotv_jax.planning.plans import load_plans
from slotv_jax.rendering.frames import CLIP_BOUNDS, MAX_FPS, check_clip
from slotv_jax.rendering.overlay import LABEL_LIFT
from slotv_jax.webstudy.stimuli import (
    MANIFEST,
    Motion,
    cross_specs,
    find_rounds,
    load_stimulus_set,
    motion_tables,
    next_round,
    round_dir,
    write_stimulus_set,
)
from slotv_jax.world import scene

IK_TOLERANCE = 5e-3  # metres: a TCP path the IK misses by more is refused
DEFAULTS = {"size": (480, 270), "fps": 25.0, "duration": 3.0, "hold": 0.5}


def robot_timing(speed: float = DEFAULT_SPEED, robot: str = "fer") -> dict:
    """The manifest's ``timing`` of clips at a Franka arm's speed (``--timed``)."""
    return {"robot": robot, "speed": check_speed(speed), "limits": SOURCE}


def check_round0_clips(stimdir: str | Path, manifest: dict) -> None:
    """ValueError naming ``stimdir`` unless the clip settings of its round 0 (``manifest``)
    are within the bounds of :func:`slotv_jax.rendering.frames.check_clip` (a later round
    has them; a timed clip's length is checked once its motion is timed)."""
    try:
        check_clip(manifest["size"], fps=manifest["fps"], duration=manifest["duration"],
                   hold=manifest["hold"])  # fmt: skip
    except ValueError as e:
        raise ValueError(f"{stimdir}: round 0's clips: {e}") from None


class SceneRenderer:
    """:class:`slotv_jax.webstudy.stimuli.Renderer` on MuJoCo (one renderer, reused).

    ``timing`` (:func:`robot_timing`; ``duration`` then None): each clip lasts as long as its
    motion's time stamps, the robot's (:func:`robot_times`)."""

    def __init__(
        self,
        size: tuple[int, int] = DEFAULTS["size"],
        fps: float = DEFAULTS["fps"],
        duration: float | None = DEFAULTS["duration"],
        hold: float = DEFAULTS["hold"],
        *,
        trace: bool = True,
        timing: dict | None = None,
    ):
        if (timing is None) == (duration is None):
            raise ValueError("duration: expected seconds of a whole motion, or a timing")
        check_clip(size, fps=fps, duration=duration, hold=hold)  # before the GL context
        self.size, self.fps, self.duration, self.hold = tuple(size), fps, duration, hold
        self.trace, self.timing = trace, timing
        self.renderer = rendering.MotionRenderer(self.size)
        # the last motion's frames by normalised time, and what they are of: its clips at
        # another τ reuse them (each moment of a motion is drawn once, whatever its τs)
        self._rendered: tuple[tuple, dict[float, np.ndarray]] = ((), {})

    @classmethod
    def like(cls, stimdir: str | Path, *, trace: bool = True) -> SceneRenderer:
        """A renderer with the size, fps, duration, hold and timing of a study folder's
        round 0, so that a later round (``study next``) looks like the first."""
        m = load_stimulus_set(stimdir, verify=False).manifest
        return cls(tuple(m["size"]), m["fps"], m["duration"], m["hold"], trace=trace,
                   timing=m.get("timing"))  # fmt: skip

    def check_times(self, t: np.ndarray, length: np.ndarray, ids: list[str]) -> None:
        """ValueError unless the clip of each motion at its robot times ``t`` (M, T) (s;
        ``length`` points each, :func:`robot_times`) is within the bounds of
        :func:`slotv_jax.rendering.frames.check_clip`: before any of them is rendered."""
        for i, tid in enumerate(ids):
            d = float(t[i, int(length[i]) - 1] - t[i, 0])
            try:
                check_clip(self.size, fps=self.fps, duration=d, hold=self.hold)
            except ValueError as e:
                raise ValueError(f"--timed: motion {tid} lasts {d:.4g} s at --speed "
                                 f"{self.timing['speed']:g}: {e}") from None  # fmt: skip

    def frames(
        self, motion: Motion, tau: float, camera: str
    ) -> tuple[UInt8[np.ndarray, "F H W 3"], Float[np.ndarray, "G 2"]]:
        """The clip cut at τ, goals labelled (no target marked), and the labels' pixels."""
        duration = self.duration if self.timing is None else motion.t[-1] - motion.t[0]
        what = (camera, float(duration), *(np.asarray(a).tobytes() for a in motion[:3]),
                None if motion.t is None else np.asarray(motion.t).tobytes())  # fmt: skip
        if self._rendered[0] != what:
            self._rendered = (what, {})
        f = rendering.motion_frames(
            motion.q, motion.goals, motion.goal_mask, camera=camera, tau=tau, size=self.size,
            fps=self.fps, duration=duration, hold=self.hold, t=motion.t,
            labels=motion.labels, trace=self.trace, renderer=self.renderer,
            rendered=self._rendered[1],
        )  # fmt: skip
        anchor = np.asarray(motion.goals, np.float64)[motion.goal_mask] + [0.0, 0.0, LABEL_LIFT]
        px, _ = rendering.pixels(anchor, camera, self.size)
        return f, px

    def write_video(self, path: Path, frames) -> None:
        rendering.write_video(path, frames, self.fps)

    def write_image(self, path: Path, image) -> None:
        rendering.write_png(path, image)

    def settings(self) -> dict:
        return {"size": list(self.size), "fps": self.fps, "duration": self.duration,
                "hold": self.hold, "timing": self.timing}  # fmt: skip

    def close(self) -> None:
        self.renderer.close()


class Motions(NamedTuple):
    """Motions to choose stimuli from, as :func:`write_stimulus_set` takes them."""

    q: np.ndarray  # (M, T, 7) joint paths (rad), padded after length
    xyz: np.ndarray  # (M, T, 3) TCP paths (m)
    goals: np.ndarray  # (M, 8, 3) goals (m)
    goal_mask: np.ndarray  # (M, 8) real goal slots
    ids: list[str]  # (M,) trajectory ids
    scenes: list[str]  # (M,) scene ids
    targets: np.ndarray | None  # (M,) target slots (None: unknown)
    length: np.ndarray  # (M,) points of each motion
    t: np.ndarray | None  # (M, T) time stamps (None: i / (length - 1))


def _ik(xyz: np.ndarray, length: np.ndarray, what: str) -> np.ndarray:
    """Joint paths of TCP paths by the project's IK from Q_HOME (a miss > 5 mm is an error)."""
    q = np.zeros((*xyz.shape[:2], 7), np.float32)
    for i in tqdm(range(len(xyz)), desc="IK", disable=len(xyz) < 20):
        q[i, : length[i]], worst = rendering.joints_from_tcp(xyz[i, : length[i]])
        if worst > IK_TOLERANCE:
            raise ValueError(f"{what} [{i}]: IK misses the path by {worst * 1e3:.1f} mm")
    return q


def robot_times(
    q: np.ndarray,
    length: np.ndarray,
    ids: list[str],
    timing: dict,
    known: Mapping[str, np.ndarray] | None = None,
) -> np.ndarray:
    """(M, T) time stamps (s) of the motions ``q`` (M, T, 7) (``length`` points each) at a
    Franka arm's speed (``timing``, :func:`robot_timing`): when the robot passes each point
    (:func:`slotv_jax.execution.time_plan`). ValueError naming the motion if it cannot.
    ``known`` ({id: (T,) times}) holds motions already timed the same way (a later round's
    check, :func:`check_ids_across_rounds`): they are not timed again."""
    cfg = TimingConfig(speed=timing["speed"], robot=timing["robot"])
    t = np.zeros(q.shape[:2])
    for i in tqdm(range(len(q)), desc="timing", disable=len(q) < 20):
        if known is not None and ids[i] in known:
            t[i] = known[ids[i]]
            continue
        L = int(length[i])
        try:
            traj = time_plan(q[i, :L], cfg)
        except (ValueError, Refused) as e:
            raise ValueError(f"--timed: motion {ids[i]}: {e}") from None
        if len(traj.knot_times) != L:
            raise ValueError(f"--timed: motion {ids[i]}: repeats a configuration (it would "
                             "stop midway); its points cannot be timed")  # fmt: skip
        t[i, :L] = traj.knot_times
        t[i, L:] = traj.knot_times[-1] + np.arange(1, q.shape[1] - L + 1)  # padding
    return t


def motions_from_split(split: Split) -> Motions:
    """A dataset split (ids ``SPLIT-INDEX``, scenes ``SPLIT-sceneENV``)."""
    n, T = split.xyz.shape[:2]
    return Motions(split.q, split.xyz, split.goals, split.goal_mask,
                   [f"{split.name}-{i}" for i in range(n)],
                   [f"{split.name}-scene{e}" for e in split.env_id], split.target,
                   np.full(n, T), None)  # fmt: skip


def motions_from_npz(path: str | Path) -> Motions:
    """The labelers' input format: ``xyz (N, T, 3)``, ``goals (N, 8, 3)`` or ``(8, 3)``,
    ``goal_mask``, optional ``t``, ``q (N, T, 7)`` (else IK) and ``target (N,)``."""
    z = load_npz(path)
    for k in ("xyz", "goals", "goal_mask"):
        if k not in z:
            raise ValueError(f"--npz {path}: missing array {k!r}; it holds {sorted(z)}")
    xyz = np.asarray(z["xyz"], np.float32)
    if xyz.ndim != 3 or xyz.shape[-1] != 3 or xyz.shape[1] < 2:
        raise ValueError(f"--npz {path}: xyz: expected (N, T >= 2, 3), got {xyz.shape}")
    n, T = xyz.shape[:2]
    goals = np.broadcast_to(z["goals"], (n, 8, 3)).astype(np.float32)
    mask = np.broadcast_to(z["goal_mask"], (n, 8)).astype(bool)
    t = None if "t" not in z else np.broadcast_to(z["t"], (n, T)).astype(np.float64)
    length = np.full(n, T)
    q = np.asarray(z["q"], np.float32) if "q" in z else _ik(xyz, length, f"--npz {path}")
    if q.shape != (n, T, 7):
        raise ValueError(f"--npz {path}: q: expected {(n, T, 7)}, got {q.shape}")
    target = None if "target" not in z else np.asarray(z["target"], int).reshape(n)
    stem = Path(path).stem
    return Motions(q, xyz, goals, mask, [f"{stem}-{i}" for i in range(n)],
                   [f"{stem}-{i}" for i in range(n)], target, length, t)  # fmt: skip


def motions_from_plans(path: str | Path) -> Motions:
    """A planning run's ``plans.npz``: every planner's plan of every problem (a planner's
    NaN rows left out); ids ``PLANNER-PROBLEM``, one scene per problem. A file without
    ``xyz`` (it is optional, e.g. the people loop's example plans) gets the TCP paths of its
    ``q`` by forward kinematics (MuJoCo C, :func:`slotv_jax.execution.models.tcp_poses`)."""
    z = load_plans(path)
    q, names = z["q"], [str(s) for s in z["names"]]
    xyz = z["xyz"] if "xyz" in z else _tcp_paths(q)  # the TCP paths go into the study's tables
    rows = [(k, p) for k in range(q.shape[0]) for p in range(q.shape[1])
            if np.isfinite(q[k, p]).all() and np.isfinite(xyz[k, p]).all()]  # fmt: skip
    ks, ps = np.array([r[0] for r in rows], int), np.array([r[1] for r in rows], int)
    return Motions(q[ks, ps].astype(np.float32), xyz[ks, ps].astype(np.float32),
                   z["goals"][ps].astype(np.float32), z["goal_mask"][ps].astype(bool),
                   [f"{names[k]}-{p}" for k, p in rows], [f"problem{p}" for p in ps],
                   z["target"][ps].astype(int), np.full(len(rows), q.shape[2]), None)  # fmt: skip


def _tcp_paths(q: np.ndarray) -> np.ndarray:
    """TCP paths (..., T, 3) of joint paths ``q`` (..., T, 7); NaN where ``q`` has a NaN."""
    flat = np.asarray(q, np.float64).reshape(-1, 7)
    ok = np.isfinite(flat).all(-1)
    out = np.full((flat.shape[0], 3), np.nan)
    out[ok] = execution_models.tcp_poses(flat[ok])[0]
    return out.reshape(*np.shape(q)[:-1], 3)


def motions_from_study(path: str | Path) -> Motions:
    """A study file (:func:`slotv_jax.study.load_study`): its trajectories, joints by IK;
    no targets (so no attention checks)."""
    st = load_study(path)
    ids = list(st.trajectory_ids) or [f"{Path(path).stem}-{i}" for i in range(st.n_trajectories)]
    ids = [re.sub(r"[^A-Za-z0-9._-]", "_", s) for s in ids]
    first: dict[str, int] = {}
    for i, s in enumerate(ids):  # distinct in the file (load_study), but maybe not once safe
        j = first.setdefault(s, i)
        if j != i:
            raise ValueError(
                f"--study {path}: trajectory ids {st.trajectory_ids[j]!r} and "
                f"{st.trajectory_ids[i]!r} are both {s!r} as stimulus ids (letters, digits "
                "and ._- only); expected ids that stay distinct"
            )
    q = _ik(st.xyz, st.length, f"--study {path}")
    return Motions(q, st.xyz, st.goals, st.goal_mask, ids, ids, None, st.length, st.t)


def check_counts(n: int, attention: int, trials: int | None) -> None:
    """ValueError unless ``n`` ≥ 1, ``attention`` ≥ 0 and ``trials`` (None: every motion) in
    1..n: the counts of :func:`make_set`, which need no motion (checked before any is
    loaded)."""
    if not (isinstance(n, int) and n >= 1):
        raise ValueError(f"--n {n}: expected an integer >= 1 (motions shown at every tau)")
    if not (isinstance(attention, int) and attention >= 0):
        raise ValueError(f"--attention {attention}: expected an integer >= 0")
    if trials is not None and not 1 <= trials <= n:
        raise ValueError(f"--trials {trials}: expected 1..{n} (--n: a participant sees each "
                         "motion at most once)")  # fmt: skip


def make_set(
    motions: Motions,
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
    round_: int = 0,
    trials: int | None = None,
    known_times: Mapping[str, np.ndarray] | None = None,
) -> dict:
    """A stimulus set of ``n`` motions drawn at random (``seed``): each at every τ from
    every camera, ``attention`` more as attention checks, one more for practice; round
    ``round_`` of its study folder (``out`` is that round's folder). Round 0 sets
    ``study.json``'s ``attention_checks`` to ``attention`` (each participant gets every
    attention check) and, with ``trials``, its ``trials_per_participant`` (each
    participant's main trials; ``None``: one per motion, or what an existing
    ``study.json`` says). ``known_times``: robot times already computed by id (what
    :func:`check_ids_across_rounds` returns), not computed again."""
    check_counts(n, attention, trials)
    m = len(motions.ids)
    need = n + attention + int(practice)
    if need > m:
        raise ValueError(
            f"--n {n}: expected n + attention + practice <= {m} (the motions), got {need}"
        )
    if attention and motions.targets is None:
        raise ValueError("--attention: the source has no targets; use --attention 0")
    pick = np.random.default_rng(seed).permutation(m)[:need]
    specs = cross_specs(
        range(n), taus=taus, cameras=cameras,
        attention=range(n, n + attention), practice=[need - 1] if practice else [],
    )  # fmt: skip
    tg = None if motions.targets is None else motions.targets[pick]
    # round 0 sets the study's study.json: each participant gets every attention check
    settings = {} if round_ else {"attention_checks": attention}
    if trials is not None:
        settings["trials_per_participant"] = trials
    t = None if motions.t is None else motions.t[pick]
    if renderer.timing is not None:  # the robot's times, before any rendering
        t = robot_times(motions.q[pick], motions.length[pick], [motions.ids[i] for i in pick],
                        renderer.timing, known=known_times)  # fmt: skip
        renderer.check_times(t, motions.length[pick], [motions.ids[i] for i in pick])
    return write_stimulus_set(
        out, q=motions.q[pick], xyz=motions.xyz[pick], goals=motions.goals[pick],
        goal_mask=motions.goal_mask[pick], ids=[motions.ids[i] for i in pick], specs=specs,
        render=renderer, scenes=[motions.scenes[i] for i in pick], targets=tg,
        length=motions.length[pick], t=t,
        source={**(source or {}), "indices": pick.tolist(), "seed": seed},
        overwrite=overwrite, progress=progress, round_=round_, settings=settings or None,
    )  # fmt: skip


def check_ids_across_rounds(
    stimdir: str | Path, motions: Motions, what: str, timing: dict | None = None
) -> dict[str, np.ndarray]:
    """ValueError unless every id of ``motions`` that a round of ``stimdir`` holds is the
    same motion there (points and goals as its tables write them): trajectory ids are
    global across the rounds of a study (:mod:`slotv_jax.webstudy.stimuli`). In a study
    timed at a robot's speed (``timing``, the manifest's), the motions' points carry the
    robot's times (:func:`robot_times`), as the new round's tables will; returns the times
    it computed ({id: (T,) s}, for :func:`make_set`'s ``known_times``; empty if none)."""
    rounds = {
        r: load_stimulus_set(round_dir(stimdir, r), verify=False) for r in find_rounds(stimdir)
    }
    seen = set().union(*(st.trajectories for st in rounds.values()))
    both = [i for i, tid in enumerate(motions.ids) if tid in seen]
    if not both:
        return {}
    ids = [motions.ids[i] for i in both]
    timed = {}
    t = None if motions.t is None else motions.t[both]
    if t is None and timing is not None:
        t = robot_times(motions.q[both], motions.length[both], ids, timing)
        timed = dict(zip(ids, t, strict=True))
    points, goals, _ = motion_tables(motions.xyz[both], motions.goals[both],
                                     motions.goal_mask[both], ids, length=motions.length[both],
                                     t=t)  # fmt: skip
    for r, st in rounds.items():
        for tid in sorted(set(points) & set(st.trajectories)):
            if st.trajectories[tid] != points[tid] or st.goals.get(tid) != goals[tid]:
                raise ValueError(
                    f"{what}: trajectory {tid!r} is another motion than the one of that id "
                    f"in round {r} of {stimdir} (ids are global across a study's rounds)"
                )
    return timed


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
    p = sub.add_parser(
        "stimuli",
        help="render a stimulus set (clips cut at tau, stills)",
        epilog=CLIP_BOUNDS,
    )
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--data", help="dataset folder (python -m slotv_jax.data), with --split")
    src.add_argument("--npz", help="trajectories in the labelers' .npz format")
    src.add_argument("--plans", help="a planning run's plans.npz (every planner's plans)")
    src.add_argument("--study", help="a study file (.npz): its trajectories")
    p.add_argument("--split", default="trajectory_test", choices=SPLITS)
    p.add_argument("--n", type=int, default=10, help="motions shown at every tau")
    p.add_argument("--taus", default="0.4,0.7,1.0", help="stop times in (0, 1]")
    p.add_argument(
        "--cameras", default="observer",
        help=f"comma-separated: cameras of the scene ({', '.join(rendering.CAMERAS)}) or the "
        "lab's camera files (*.json: position, look_at or rotation, fovy)",
    )  # fmt: skip
    p.add_argument("--attention", type=int, default=2,
                   help="attention-check motions (tau 1), each shown to every participant "
                   "(study.json's attention_checks)")  # fmt: skip
    p.add_argument("--trials", type=int, default=None,
                   help="main trials a participant sees, each of another motion (default: "
                   "every motion); study.json's trials_per_participant")  # fmt: skip
    p.add_argument("--no-practice", action="store_true", help="no practice trial")
    p.add_argument("--size", default=None, help="WIDTHxHEIGHT of the clips (480x270)")
    p.add_argument("--fps", type=float, default=None,
                   help=f"frames per second (25; at most {MAX_FPS:g})")  # fmt: skip
    p.add_argument("--duration", type=float, default=None,
                   help="seconds of a whole motion, tau = 1 (3)")  # fmt: skip
    p.add_argument("--hold", type=float, default=None,
                   help="seconds the last frame stays (0.5)")  # fmt: skip
    add_timing_args(p, instead="--duration seconds")
    p.add_argument("--no-trace", action="store_true", help="do not draw the TCP's path")
    p.add_argument("--seed", type=int, default=0)
    dest = p.add_mutually_exclusive_group(required=True)
    dest.add_argument("--out", help="the study folder to write (its round 0)")
    dest.add_argument("--next-round", metavar="STIMDIR",
                      help="or: add the set to this study folder as its next round, with "
                      "round 0's clip settings (a running server picks it up)")  # fmt: skip
    p.add_argument("--overwrite", action="store_true", help="replace an earlier set there")


def stimuli_main(args: argparse.Namespace) -> int:
    """Check every input and the output folder, then render the set (round 0, or with
    ``--next-round`` the study folder's next round)."""
    taus = _floats(args.taus, "--taus")
    validation.check_seeds("--seed", args.seed)
    clip = {k: getattr(args, k) for k in ("size", "fps", "duration", "hold")}
    size = _size(args.size or "x".join(map(str, DEFAULTS["size"])))
    cameras = tuple(c.strip() for c in args.cameras.split(","))
    for c in cameras:  # a name or a camera file, read and checked before anything is loaded
        try:
            scene.check_camera(c)
        except ValueError as e:
            raise ValueError(f"--cameras {args.cameras}: {e}") from None
    check_counts(args.n, args.attention, None if args.next_round else args.trials)
    for name in ("fps", "duration"):
        if not (clip[name] is None or clip[name] > 0):
            raise ValueError(f"--{name} {clip[name]}: expected a number > 0")
    if not (args.hold is None or args.hold >= 0):
        raise ValueError(f"--hold {args.hold}: expected seconds >= 0")
    if args.timed and clip["duration"] is not None:
        raise ValueError("--duration: --timed shows each motion at the robot's own speed; "
                         "leave --duration out")  # fmt: skip
    fps = clip["fps"] or DEFAULTS["fps"]
    duration = None if args.timed else clip["duration"] or DEFAULTS["duration"]
    hold = DEFAULTS["hold"] if args.hold is None else args.hold
    if args.next_round is None:  # the clips within their bounds, before anything is loaded
        check_clip(size, fps=fps, duration=duration, hold=hold, prefix="--")
    timed = timing_from_args(args)
    timing = None if timed is None else robot_timing(timed.speed, timed.robot)
    inputs = {f"--{k}": getattr(args, k) for k in ("data", "npz", "plans", "study")}
    if args.next_round is not None:  # the next round's folder, with round 0's clip settings
        stimdir = Path(args.next_round)
        given = [k for k, v in clip.items() if v is not None] + ["timed"] * args.timed
        if given:
            raise ValueError(f"--{given[0]}: --next-round keeps round 0's clip settings; "
                             "leave it out")  # fmt: skip
        if args.overwrite:
            raise ValueError("--overwrite: --next-round writes a new round, never over one")
        if args.trials is not None:
            raise ValueError(f"--trials: --next-round keeps the study's settings; set "
                             f"trials_per_participant in {stimdir / 'study.json'}")  # fmt: skip
        if not find_rounds(stimdir):
            raise ValueError(f"--next-round {stimdir}: no study folder ({MANIFEST} of "
                             "round 0 missing; `study stimuli --out` writes one)")  # fmt: skip
        r, folder = next_round(stimdir)
        check_not_input(folder, inputs, what="--next-round", replaces_dir=True)
        manifest0 = load_stimulus_set(stimdir, verify=False).manifest
        check_round0_clips(f"--next-round {stimdir}", manifest0)  # before any loading
    else:
        stimdir = folder = Path(args.out)
        check_not_input(folder, inputs, replaces_dir=True)
        check_output_dir(folder, ours=lambda p: (p / MANIFEST).is_file(),
                         overwrite=args.overwrite)  # fmt: skip
        r = 0
    if args.data is not None:
        motions, source = motions_from_split(load_split(args.data, args.split)), {
            "kind": "split", "data": str(args.data), "split": args.split}  # fmt: skip
    elif args.npz is not None:
        motions, source = motions_from_npz(args.npz), {"kind": "npz", "file": str(args.npz)}
    elif args.plans is not None:
        motions, source = motions_from_plans(args.plans), {"kind": "plans", "file": args.plans}
    else:
        motions, source = motions_from_study(args.study), {"kind": "study", "file": args.study}
    known = {}  # robot times the check computed: make_set does not compute them again
    if r:
        flag, path = next((k, v) for k, v in inputs.items() if v is not None)
        timing0 = manifest0.get("timing")
        known = check_ids_across_rounds(stimdir, motions, f"{flag} {path}", timing0)
    try:
        if r:
            renderer = SceneRenderer.like(stimdir, trace=not args.no_trace)
        else:
            renderer = SceneRenderer(size, fps, duration, hold, trace=not args.no_trace,
                                     timing=timing)  # fmt: skip
    except rendering.RenderBackendError as e:
        raise ValueError(str(e)) from None  # one line: how to get OpenGL
    try:
        m = make_set(
            motions, folder, n=args.n, taus=taus, cameras=cameras, attention=args.attention,
            practice=not args.no_practice, seed=args.seed, renderer=renderer,
            overwrite=args.overwrite, source=source, round_=r, trials=args.trials,
            known_times=known,
        )  # fmt: skip
    finally:
        renderer.close()
    what = f"round {r} of {stimdir}" if r else args.out
    print(f"wrote {what}: {len(m['stimuli'])} stimuli ({folder}/{MANIFEST})")
    return 0
