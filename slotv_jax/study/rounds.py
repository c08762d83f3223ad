"""The next round of a study: train on the answers so far, choose what to ask next.

``python -m slotv_jax.study next --stimuli STIMDIR --answers DIR --data DATA --split NAME
--n N`` (or ``--db FILE`` instead of ``--answers``):

1. reads the answers so far: the tables ``study export`` wrote (``answers.csv``,
   ``trajectories.csv``, ``goals.csv`` in ``DIR``), or the server's SQLite database;
2. trains an ensemble of observers on them (:mod:`slotv_jax.selection`; the paper's MLP
   or SLOT-V+ with ``--model slotv_plus``), every member on the count likelihood of the
   guesses;
3. scores candidate stimuli, the motions of a dataset split at each stop time of
   ``--taus`` that no earlier round showed (a random ``--subset`` of them), and picks
   ``--n`` of them by ``--strategy`` (default ``margin``: the motions nearest the
   observer's decision between two goals, never behind random selection in the simulated
   studies of ``experiments.active`` at either preset; ``error`` needed the fewest answers
   with the paper's network, ``experiments/active_paper_error``, but fell behind margin
   with the quick one);
4. renders them as the next round of the study folder, ``STIMDIR/round-R`` (round 0 is
   the folder itself), with the renderer settings of round 0, plus attention checks and
   a practice trial as ``study stimuli`` adds them. The server (``study serve``) serves a
   new round to new participants without a restart.

The round's manifest records in ``source`` what chose it: the strategy, model, answers,
the members' agreement and each pick's score.
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import functools
import json
import tempfile
from collections.abc import Sequence
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from slotv_jax import rendering
from slotv_jax.answers.format import Study
from slotv_jax.answers.tables import read_tables
from slotv_jax.asking import selection
from slotv_jax.core import validation
from slotv_jax.data import SPLITS, load_split
from slotv_jax.training import config as train_config
from slotv_jax.webstudy import export as export_lib
from slotv_jax.webstudy import make_stimuli, stimuli
from slotv_jax.webstudy.database import connect
from slotv_jax.world import scene

MODELS = ("mlp", "slotv_plus")  # observers of prefixes (archetypes score whole motions)


def read_answers(answers: str | Path | None = None, db: str | Path | None = None) -> Study:
    """The answers so far as a :class:`slotv_jax.Study`: from an exported folder
    (``answers.csv``, ``trajectories.csv``, ``goals.csv``) or the server's database."""
    if (answers is None) == (db is None):
        raise ValueError("--answers / --db: give one of them")
    if db is not None:
        db = Path(db)
        storage = connect(db, create=False)  # a missing, empty or damaged file: refused
        with tempfile.TemporaryDirectory() as tmp:
            tabs = export_lib.tables(storage)
            for name in ("answers", "trajectories", "goals"):
                (Path(tmp) / f"{name}.csv").write_text(tabs[name])
            if len(tabs["answers"].strip().splitlines()) < 2:
                raise ValueError(f"--db {db}: no answers yet")
            return read_tables(*(Path(tmp) / f"{n}.csv" for n in ("trajectories", "goals",
                                                                        "answers")))[0]  # fmt: skip
    folder = Path(answers)
    files = [folder / f"{n}.csv" for n in ("trajectories", "goals", "answers")]
    missing = [f.name for f in files if not f.is_file()]
    if missing:
        raise ValueError(f"--answers {folder}: missing {', '.join(missing)} (study export)")
    return read_tables(*files)[0]


def check_answers(answers: Study) -> Study:
    """``answers``, or ValueError naming ``--answers / --db`` if it holds none yet."""
    if answers.n_rows == 0:
        raise ValueError("--answers / --db: the study has no answers yet; run round 0 first")
    return answers


def shown_stimuli(stimdir: str | Path) -> set[tuple[str, float]]:
    """(trajectory id, τ) of every trial stimulus in the study folder's rounds."""
    out = set()
    for r in stimuli.find_rounds(stimdir):
        m = json.loads((stimuli.round_dir(stimdir, r) / stimuli.MANIFEST).read_text())
        out |= {(s["trajectory"], round(float(s["tau"]), 6)) for s in m["stimuli"]}
    return out


def trial_count(stimdir: str | Path) -> int:
    """How many trial stimuli (not checks or practice) the study folder's rounds hold: what
    ``study next --budget`` counts."""
    n = 0
    for r in stimuli.find_rounds(stimdir):
        m = json.loads((stimuli.round_dir(stimdir, r) / stimuli.MANIFEST).read_text())
        n += sum(s["kind"] == "trial" for s in m["stimuli"])
    return n


_SELECT = jax.jit(selection.select, static_argnums=(0, 4))


@functools.cache
def _compiled(sel: selection.Selector):
    """The selector's jitted ``fit`` and ``log_probs`` (one compilation per selector)."""
    return jax.jit(sel.fit, static_argnames="updates"), jax.jit(sel.log_probs)


def _pad(a: np.ndarray, t: int) -> np.ndarray:
    return np.concatenate([a, np.zeros((a.shape[0], t - a.shape[1], *a.shape[2:]), a.dtype)], 1)


def choose(
    answers: Study,
    motions: make_stimuli.Motions,
    *,
    n: int,
    taus: Sequence[float],
    strategy: str = "margin",
    cfg: train_config.TrainConfig | None = None,
    members: int = 4,
    updates: int = 500,
    subset: int = 5000,
    exclude: set[tuple[str, float]] = frozenset(),
    seed: int = 0,
    groups: Sequence[str] | None = None,
) -> dict:
    """Train an ensemble on ``answers`` and pick ``n`` (motion, τ) stimuli of ``motions``.

    The pool joins the answered trajectories (each answer row a candidate at its own
    stop) and the candidates, every motion at every τ, less those in ``exclude``
    ((trajectory id, τ) pairs). With ``groups`` (one name per motion, e.g. the planner of
    each plan), the picks go round the groups in turn, each group's best by the strategy's
    ranking score first, so that every group is asked about (a round of plans covers every
    planner). Returns {"picks": [(motion index, τ), ...], "scores", "strategy", "answers",
    "rows", "candidates", "agreement"}.
    """
    check_answers(answers)
    if strategy not in selection.STRATEGIES:
        raise ValueError(f"--strategy: expected one of {selection.STRATEGIES}, got {strategy!r}")
    cfg = train_config.quick("slotv", train_size=None) if cfg is None else cfg
    if cfg.model != "mlp":
        raise ValueError("--model: study next trains the MLP family (mlp, slotv_plus)")
    taus = np.asarray(sorted({float(t) for t in taus}))
    m, t_motion = len(motions.ids), motions.xyz.shape[1]
    seen = np.minimum(selection.seen_points(taus, t_motion)[None, :], motions.length[:, None])
    cand = [(i, j) for i in range(m) for j in range(taus.size)
            if (motions.ids[i], round(float(taus[j]), 6)) not in exclude]  # fmt: skip
    if len(cand) < n:
        raise ValueError(f"--n {n}: only {len(cand)} candidate stimuli are left unshown")
    rng = np.random.default_rng(seed)
    if len(cand) > subset:
        cand = [cand[k] for k in np.sort(rng.choice(len(cand), subset, replace=False))]
    t_max = max(answers.xyz.shape[1], t_motion)
    na = answers.n_trajectories
    xyz = np.concatenate([_pad(answers.xyz, t_max), _pad(motions.xyz, t_max)])
    goals = np.concatenate([answers.goals, motions.goals]).astype(np.float32)
    mask = np.concatenate([answers.goal_mask, motions.goal_mask])
    rows = answers.n_rows
    traj = np.r_[answers.answer_trajectory, [na + i for i, _ in cand]].astype(np.int32)
    pts = np.r_[answers.seen(), [seen[i, j] for i, j in cand]].astype(np.int32)
    pool = selection.Pool(jnp.asarray(xyz, jnp.float32), jnp.asarray(goals), jnp.asarray(mask),
                          jnp.asarray(traj), jnp.asarray(pts))  # fmt: skip
    ans = selection.make_answers(np.arange(rows), answers.counts, rows)
    sel = selection.make_selector(cfg, members, rows)
    key = jax.random.key(seed)
    ens = sel.init(key)
    fit, log_probs = _compiled(sel)
    ens, _ = fit(ens, pool, ans, jax.random.fold_in(key, 1), updates=updates)
    idx = jnp.arange(rows, rows + len(cand))
    logp = log_probs(ens.params, pool, idx)
    k = jax.random.fold_in(key, 2)
    name, score = selection.ranking_score(strategy, k, logp)
    score = np.asarray(score)
    if groups is None:
        pick = np.asarray(_SELECT(strategy, k, logp, jnp.ones(len(cand), bool), n))
    else:
        pick = _round_robin([groups[i] for i, _ in cand], score, n)
    return {
        "picks": [(cand[p][0], float(taus[cand[p][1]])) for p in pick],
        "scores": [round(float(score[p]), 6) for p in pick],
        "score": name,
        "strategy": strategy,
        "answers": answers.n_answers,
        "rows": rows,
        "candidates": len(cand),
        "agreement": round(float(np.mean(selection.bald(logp) < 0.01)), 4),
    }


def _round_robin(groups: Sequence[str], score: np.ndarray, n: int) -> np.ndarray:
    """``n`` candidates, the groups in turn (in order of first appearance), each group's
    next-best by ``score`` (highest first; ties by position).

    >>> _round_robin(["a", "a", "b", "a"], np.array([0.1, 0.9, 0.2, 0.5]), 3).tolist()
    [1, 2, 3]
    """
    order: dict[str, list[int]] = {}
    for c in np.argsort(-np.asarray(score), kind="stable"):
        order.setdefault(groups[c], []).append(int(c))
    out: list[int] = []
    while len(out) < n:
        for g in dict.fromkeys(groups):
            if order[g] and len(out) < n:
                out.append(order[g].pop(0))
    return np.asarray(out, int)


def plans_round(
    path: str | Path, answers: Study, round_: int
) -> tuple[make_stimuli.Motions, list[str]]:
    """A pick's plans (``study pick --by plans`` or ``pool``, ``DIR/plans.npz``) as the
    candidate motions of a round of plans, and each one's planner. Every problem must be
    a scene the study's answers are about (plans of another study are refused); the ids
    become ``rR-PLANNER-PROBLEM``, so that plans made after each round are new motions."""
    m = make_stimuli.motions_from_plans(path)
    seen = {_scene_key(g, k) for g, k in zip(answers.goals, answers.goal_mask, strict=True)}
    for i, (g, k) in enumerate(zip(m.goals, m.goal_mask, strict=True)):
        if _scene_key(g, k) not in seen:
            raise ValueError(
                f"--plans {path}: plan {m.ids[i]}'s scene is none of the study's answered "
                "scenes (plans or a pick of another study?)"
            )
    planners = [tid.rsplit("-", 1)[0] for tid in m.ids]
    return m._replace(ids=[f"r{round_}-{tid}" for tid in m.ids]), planners


def _scene_key(goals: np.ndarray, mask: np.ndarray) -> bytes:
    """A scene's real goals rounded to 0.1 mm (its tables keep six decimals)."""
    return np.round(np.asarray(goals, np.float64)[np.asarray(mask, bool)], 4).tobytes()


def write_round(
    stimdir: str | Path,
    motions: make_stimuli.Motions,
    picks: Sequence[tuple[int, float]],
    *,
    renderer,
    cameras: Sequence[str] = ("observer",),
    attention: int = 2,
    practice: bool = True,
    source: dict | None = None,
    seed: int = 0,
    progress: bool = True,
) -> tuple[int, dict]:
    """Render ``picks`` ((motion index, τ) pairs) as the next round of ``stimdir``, with
    ``attention`` checks (τ = 1) and a practice trial from other motions. Returns the
    round number and its manifest."""
    r, out = stimuli.next_round(stimdir)
    used = list(dict.fromkeys(i for i, _ in picks))
    others = [i for i in np.random.default_rng([seed, r]).permutation(len(motions.ids))
              if i not in set(used)][: attention + int(practice)]  # fmt: skip
    if len(others) < attention + int(practice):
        raise ValueError("--attention: too few motions left for the checks and the practice")
    rows = used + others
    where = {i: k for k, i in enumerate(rows)}
    specs = [stimuli.StimulusSpec(where[i], float(tau), c) for i, tau in picks for c in cameras]
    specs += [stimuli.StimulusSpec(where[i], 1.0, cameras[0], "attention")
              for i in others[:attention]]  # fmt: skip
    if practice:
        specs.append(stimuli.StimulusSpec(where[others[-1]], 1.0, cameras[0], "practice"))
    rows = np.asarray(rows)
    t = None if motions.t is None else motions.t[rows]
    if getattr(renderer, "timing", None) is not None:  # round 0 at the robot's speed: so this
        t = make_stimuli.robot_times(motions.q[rows], motions.length[rows],
                                     [motions.ids[i] for i in rows], renderer.timing)  # fmt: skip
        renderer.check_times(t, motions.length[rows], [motions.ids[i] for i in rows])
    manifest = stimuli.write_stimulus_set(
        out, q=motions.q[rows], xyz=motions.xyz[rows], goals=motions.goals[rows],
        goal_mask=motions.goal_mask[rows], ids=[motions.ids[i] for i in rows], specs=specs,
        render=renderer, scenes=[motions.scenes[i] for i in rows],
        targets=None if motions.targets is None else motions.targets[rows],
        length=motions.length[rows], t=t, round_=r, source=source, progress=progress,
    )  # fmt: skip
    return r, manifest


def add_command(sub) -> None:
    """Add ``next`` to the study CLI's subparsers."""
    p = sub.add_parser("next", help="train on the answers so far, render the next round")
    p.add_argument("--stimuli", required=True, help="the study folder (its rounds)")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--answers", help="folder of the exported tables (study export)")
    src.add_argument("--db", help="the server's SQLite database")
    what = p.add_mutually_exclusive_group(required=True)
    what.add_argument("--data", help="dataset folder of the candidate motions")
    what.add_argument("--plans", help="a round of plans: a pick's plans.npz (study pick --by "
                      "plans or pool), every planner asked about in turn")  # fmt: skip
    p.add_argument("--split", default="trajectory_test", choices=SPLITS)
    p.add_argument("--n", type=int, default=10, help="stimuli to choose")
    p.add_argument(
        "--budget", type=int, default=None,
        help="the most trial stimuli of every round together (default: no bound)",
    )  # fmt: skip
    p.add_argument("--taus", default="0.4,0.7,1.0", help="candidate stop times in (0, 1]")
    p.add_argument("--strategy", default="margin", choices=selection.STRATEGIES)
    p.add_argument("--model", default="mlp", choices=MODELS)
    p.add_argument("--preset", default="quick", choices=tuple(train_config.PRESETS))
    p.add_argument("--members", type=int, default=4, help="ensemble size")
    p.add_argument("--updates", type=int, default=500, help="training updates per member")
    p.add_argument("--subset", type=int, default=5000, help="candidates scored (at random)")
    p.add_argument("--cameras", default="observer")
    p.add_argument("--attention", type=int, default=2, help="attention-check motions")
    p.add_argument("--no-practice", action="store_true")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--no-progress", action="store_true")


def next_main(args: argparse.Namespace) -> int:
    """Check the inputs, choose the stimuli, render the round."""
    stimdir = Path(args.stimuli)
    validation.check_seeds("--seed", args.seed)
    r, out = stimuli.next_round(stimdir)  # errors if the folder holds no round 0
    taus = [float(x) for x in args.taus.split(",")]
    selection.seen_points(taus, 2)  # checks the τ
    for name in ("n", "members", "updates", "subset"):
        if getattr(args, name) < 1:
            raise ValueError(f"--{name} {getattr(args, name)}: expected an integer >= 1")
    if args.attention < 0:
        raise ValueError(f"--attention {args.attention}: expected an integer >= 0")
    cameras = [c.strip() for c in args.cameras.split(",")]
    for c in cameras:
        try:
            scene.check_camera(c)
        except ValueError as e:
            raise ValueError(f"--cameras {args.cameras}: {e}") from None
    if args.budget is not None:
        new, shown = args.n * len(cameras), trial_count(stimdir)
        if args.budget < 1 or shown + new > args.budget:
            raise ValueError(
                f"--n {args.n}: {new} more trial stimuli ({len(cameras)} camera(s)) and the "
                f"{shown} of the rounds so far exceed --budget {args.budget}"
            )
    try:  # the round is rendered last, after the ensemble's training: say now if it cannot be
        rendering.check_backend()
    except rendering.RenderBackendError as e:
        raise ValueError(str(e)) from None
    settings = json.loads((stimuli.round_dir(stimdir, 0) / stimuli.MANIFEST).read_text())
    make_stimuli.check_round0_clips(f"--stimuli {stimdir}", settings)  # before any training
    answers = check_answers(read_answers(args.answers, args.db))  # before loading motions
    groups = None
    if args.plans is not None:
        motions, groups = plans_round(args.plans, answers, r)
    else:
        motions = make_stimuli.motions_from_split(load_split(args.data, args.split))
    cfg = train_config.preset(args.preset, "slotv", train_size=None)
    if args.model == "slotv_plus":
        cfg = dataclasses.replace(cfg, start_term=True, time_weight=True)
    choice = choose(
        answers, motions, n=args.n, taus=taus, strategy=args.strategy, cfg=cfg,
        members=args.members, updates=args.updates, subset=args.subset,
        exclude=shown_stimuli(stimdir), seed=args.seed, groups=groups,
    )  # fmt: skip
    renderer = make_stimuli.SceneRenderer(
        tuple(settings["size"]),
        settings["fps"],
        settings["duration"],
        settings["hold"],
        timing=settings.get("timing"),
    )
    source = {"kind": "active", "model": args.model,
              **({"plans": str(args.plans)} if args.plans else
                 {"data": str(args.data), "split": args.split}),
              **{k: v for k, v in choice.items() if k != "picks"}}  # fmt: skip
    try:
        r, manifest = write_round(
            stimdir, motions, choice["picks"], renderer=renderer,
            cameras=cameras, attention=args.attention,
            practice=not args.no_practice, source=source, seed=args.seed,
            progress=not args.no_progress,
        )  # fmt: skip
    finally:
        renderer.close()
    kinds = collections.Counter(s["kind"] for s in manifest["stimuli"])
    extra = ", ".join(f"{kinds[k]} {k}" for k in ("attention", "practice") if kinds[k])
    print(
        f"round {r}: {len(manifest['stimuli'])} stimuli in {out} ("
        f"{kinds['trial']} trials{', ' + extra if extra else ''}; {choice['strategy']} of "
        f"{choice['candidates']} candidates, trained on {choice['answers']:g} answers)"
    )
    return 0
