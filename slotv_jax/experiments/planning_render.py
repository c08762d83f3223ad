"""The planning experiment's plans, seen: the Panda from the observer's camera, one row
per scene and one panel per planner (straight line, oracle, learned observers).

    python -m slotv_jax.experiments.planning_render --plans experiments/planning_plans.npz \\
        --out experiments/planning_render.png

Reads a planning run's ``plans.npz`` (:mod:`slotv_jax.planning.plans`; ``family``
where it has one) and renders, for each chosen problem, every planner's
motion up to τ (default 0.6: what an observer has seen before the end, when a legible
motion should already give its goal away), with the TCP's path so far, the target's cube
on a white disc and the cubes lettered, from the ``observer_angle`` camera (45° round
from the ``observer`` camera, so that the paths are not seen end-on). By default it
shows three problems, the families (labelers) in turn (:func:`default_problems`).
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from slotv_jax.core import cli, fileio
from slotv_jax.planning.plans import load_plans
from slotv_jax.render.cli import parse_indices, parse_size
from slotv_jax.rendering import compare, writers
from slotv_jax.rendering.camera import CAMERAS, View
from slotv_jax.rendering.frames import MotionRenderer, RenderBackendError, check_timing
from slotv_jax.rendering.overlay import title


def default_problems(family: np.ndarray, n: int = 3) -> list[int]:
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


DEFAULT_PLANNERS = ("straight", "oracle", "slotv", "slotv_plus")  # shown when present


def choose_planners(
    plans: dict[str, np.ndarray], problems: Sequence[int], wanted: Sequence[str] | None = None
) -> list[int]:
    """Planner rows of ``plans`` to show: ``wanted`` (default :data:`DEFAULT_PLANNERS`,
    or every planner if none of those is there), less those with a non-finite plan
    (a planner left out of a family) in any chosen problem."""
    names = [str(s) for s in plans["names"]]
    if wanted is not None:
        unknown = [w for w in wanted if w not in names]
        if unknown:
            raise ValueError(f"--planners: {unknown} not in the plans' names {names}")
        ks = [names.index(w) for w in wanted]
    else:
        ks = [names.index(w) for w in DEFAULT_PLANNERS if w in names] or list(range(len(names)))
    q = plans["q"][:, list(problems)]
    return [k for k in ks if np.isfinite(q[k]).all()]


def figure(
    plans: dict[str, np.ndarray],
    problems: Sequence[int],
    *,
    planners: Sequence[int] | None = None,
    tau: float = 0.6,
    camera: View = "observer_angle",
    size: tuple[int, int] = (480, 270),
    renderer: MotionRenderer | None = None,
) -> np.ndarray:
    """One image: a row per problem, a panel per planner (rows of ``plans["names"]``),
    each row captioned; with ``y`` in ``plans``, each panel's title gives the probability
    of the target that the family's labeler assigns to the whole motion."""
    names = [str(s) for s in plans["names"]]
    ks = list(range(len(names))) if planners is None else list(planners)
    if not ks:
        raise ValueError("planners: none left to show (all missing or non-finite)")
    rows = []
    for p in problems:
        target = int(plans["target"][p])
        titles = [names[k] for k in ks]
        if "y" in plans:
            titles = [f"{names[k]}: P = {plans['y'][k, p, target]:.2f}" for k in ks]
        frames = compare.compare_frames(
            [plans["q"][k, p] for k in ks],
            plans["goals"][p],
            plans["goal_mask"][p],
            names=titles,
            rgbas=[compare.PALETTE[k % len(compare.PALETTE)] for k in ks],
            tau=tau,
            camera=camera,
            size=size,
            fps=1.0 / tau,
            duration=1.0,
            hold=0.0,
            target=target,
            renderer=renderer,
        )
        fam = str(plans["family"][p]) if "family" in plans else ""
        goal = chr(ord("A") + target)
        caption = f"problem {p}{f' ({fam})' if fam else ''}: to cube {goal}, seen up to τ = {tau:g}"
        rows.append(np.concatenate([title(frames[-1], caption), frames[-1]]))
        rows.append(np.full((compare.GAP, frames.shape[2], 3), 255, np.uint8))
    return np.concatenate(rows[:-1])


@cli.command
def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m slotv_jax.experiments.planning_render")
    p.add_argument("--plans", required=True, type=Path, help="a planning run's plans.npz")
    p.add_argument("--out", required=True, type=Path, help="output .png")
    p.add_argument("--problems", help="I, A:B or I,J,K (default: 3, the families in turn)")
    p.add_argument("--planners", help=f"comma-separated (default: {','.join(DEFAULT_PLANNERS)})")
    p.add_argument("--tau", type=float, default=0.6, help="show the motions up to τ")
    p.add_argument("--camera", default="observer_angle", choices=CAMERAS, help="scene camera")
    p.add_argument("--size", default="480x270", help="one panel's size WxH")
    args = p.parse_args(argv)
    if args.out.suffix.lower() != ".png":
        raise cli.InputError(f"--out {args.out}: expected a .png file")
    fileio.check_output_files(args.out.parent, [args.out.name])  # a figure, regenerated
    check_timing(args.tau, 1.0, 1.0, 0.0)
    size = parse_size(args.size)
    plans = load_plans(args.plans)
    n = plans["q"].shape[1]
    if args.problems:
        problems = parse_indices(args.problems, n, "--problems")
    else:
        problems = default_problems(plans.get("family", np.zeros(n, str)))
    wanted = None if args.planners is None else [w.strip() for w in args.planners.split(",")]
    planners = choose_planners(plans, problems, wanted)
    if not planners:
        raise cli.InputError(f"--plans {args.plans}: no planner with finite plans to show")
    try:
        renderer = MotionRenderer(size)
    except RenderBackendError as e:
        raise cli.InputError(str(e)) from None
    with renderer:
        img = figure(
            plans,
            problems,
            planners=planners,
            tau=args.tau,
            camera=args.camera,
            size=size,
            renderer=renderer,
        )
    writers.write_png(args.out, img)
    print(f"wrote {args.out} ({len(problems)} problems x {len(planners)} planners)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
