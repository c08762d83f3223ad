"""One small run through everything real (issue 37, item 4): ask, learn, plan, evaluate.

Rendered stimuli of a dataset split, ``study serve`` with its SQLite database (one server
process for the whole run), participants of the default population answering over HTTP
(``study simulate --population default``), ``study export``, ``study import``, the
dragan archetype trained on the answers (``python -m slotv_jax.train --study``), a plan
with the prefix objective from the loaded observer, and the plan (beside the straight
line of the same problem) rendered as the next round of the same study folder
(``study stimuli --plans ... --next-round``), which the running server gives to new
participants, whose answers it stores.

The commands run in this process through their command lines (``main(argv)``: the same
parser and checks as in a shell, without a Python start-up per step); the server runs as
the separate process a researcher starts. Each check compares with what was stored or
given, read independently: the database with ``sqlite3``, the plan's end with MuJoCo C's
forward kinematics (the planner uses MJX), the served still with a fresh rendering.
"""

from __future__ import annotations

import asyncio
import hashlib
import io
import sqlite3
from collections import Counter
from pathlib import Path

import jax
import numpy as np
import pytest
from PIL import Image
from study_fixtures import DotRenderer, ServerProcess, motions

import slotv_jax
from slotv_jax import data, planning, render
from slotv_jax.answers.storage import load_study
from slotv_jax.study import cli as study_cli
from slotv_jax.train import cli as train_cli
from slotv_jax.training import checkpoint
from slotv_jax.webstudy import client, make_stimuli, stimuli

TAUS = (0.4, 1.0)
CLIP = ["--size", "64x48", "--fps", "4", "--duration", "1", "--hold", "0"]
FIRST, EVAL = 12, 6  # participants of round 0, of the evaluation round


def run(main, *argv) -> None:
    """A command line, as a shell would run it (``error: ...`` exits with 2)."""
    assert main([str(a) for a in argv]) == 0


def stored(db: Path) -> list[tuple]:
    """Every stored answer: (external id, round, position, stimulus id, trajectory, τ,
    kind, guess), by participant and position."""
    con = sqlite3.connect(db)
    rows = con.execute(
        "SELECT p.external_id, s.round, t.position, s.id, s.trajectory, s.tau, s.kind, "
        "a.guess FROM answers a JOIN trials t ON t.trial = a.trial JOIN stimuli s ON "
        "s.stimulus = t.stimulus JOIN participants p ON p.participant = t.participant "
        "ORDER BY p.participant, t.position"
    ).fetchall()
    con.close()
    return rows


def replayed(stim: Path, rows: list[tuple], seed: int) -> dict[str, list[str]]:
    """The guesses each simulated participant makes on the stills of their stored trials,
    in order: participant ``sim-i`` of ``study simulate --seed`` draws from (seed, i)."""
    crowd = client.PopulationGuesser(stim, "default", seed=seed)
    out: dict[str, list[str]] = {}
    for ext in dict.fromkeys(r[0] for r in rows):
        person = crowd.participant(int(ext.removeprefix("sim-")))
        out[ext] = []
        for _, r, _, sid, *_ in (x for x in rows if x[0] == ext):
            still = (stimuli.round_dir(stim, r) / "stills" / f"{sid}.png").read_bytes()
            out[ext].append(person({}, still))
    return out


@pytest.mark.slow  # 44-97 s on a shared 2-core CPU (load 3.6-6.7); ~35 s compiling the planner
def test_ask_learn_plan_evaluate_through_the_real_study(tiny_data, tiny_cfg, tmp_path, capsys):
    home, stim, db = tmp_path / "data", tmp_path / "stim", tmp_path / "study.db"
    home.mkdir()
    data.save_split(home, tiny_data["trajectory_test"], tiny_cfg)
    # ---- ask: 3 dataset motions at two stop times, one attention check, one practice
    run(study_cli.main, "stimuli", "--data", home, "--split", "trajectory_test", "--n", 3,
        "--taus", ",".join(map(str, TAUS)), "--attention", 1, *CLIP, "--out", stim)  # fmt: skip
    server = ServerProcess(stim, db)
    try:
        run(study_cli.main, "simulate", "--url", server.url, "--stimuli", stim,
            "--participants", FIRST, "--population", "default", "--seed", 0)  # fmt: skip
        out = capsys.readouterr().out
        assert (f"{FIRST} of {FIRST} simulated participants finished, {5 * FIRST} answers "
                f"({3 * FIRST} on the stimuli, {FIRST} attention checks, {FIRST} practice "
                "trials") in out  # fmt: skip
        rows0 = stored(db)
        # the database holds exactly the acknowledged answers: each participant's guesses
        # on the stills they were shown, in order, once each
        assert len(rows0) == 5 * FIRST
        assert {r[0] for r in rows0} == {f"sim-{i}" for i in range(FIRST)}
        got = {e: [r[7] for r in rows0 if r[0] == e] for e in dict.fromkeys(r[0] for r in rows0)}
        assert got == replayed(stim, rows0, seed=0)
        for e in got:  # positions 0..4: the practice first, 3 motions, 1 check
            mine = [r for r in rows0 if r[0] == e]
            assert [r[2] for r in mine] == list(range(5)) and mine[0][6] == "practice"
            assert sorted(r[6] for r in mine) == ["attention", "practice", *["trial"] * 3]

        # ---- learn: export, import, the dragan archetype on the answers
        run(study_cli.main, "export", "--db", db, "--out", tmp_path / "answers")
        a, npz = tmp_path / "answers", tmp_path / "people.npz"
        run(study_cli.main, "import", "--trajectories", a / "trajectories.csv", "--goals",
            a / "goals.csv", "--answers", a / "answers.csv", "--out", npz)  # fmt: skip
        people = load_study(npz)
        trial = Counter((r[4], round(r[5], 6), r[7]) for r in rows0 if r[6] == "trial")
        counts = Counter()
        for i, n in enumerate(people.answer_trajectory):
            m = people.goal_mask[n]
            for g, c in zip(people.goal_names[n][m], people.counts[i][m].tolist(), strict=True):
                if c:
                    counts[(people.trajectory_ids[n], round(float(people.answer_tau[i]), 6),
                            str(g))] += int(c)  # fmt: skip
        assert counts == trial and people.n_answers == 3 * FIRST
        run(train_cli.main, "--study", npz, "--model", "dragan", "--method",
            "slotv", "--epochs", 10, "--set", "batch_size=2", "--out", tmp_path / "ckpt",
            "--no-progress")  # fmt: skip
        observer = slotv_jax.load_observer(tmp_path / "ckpt", model="dragan")
        _, state, _ = checkpoint.restore(tmp_path / "ckpt")
        leaves = jax.tree.leaves(state.params)
        assert leaves and all(np.isfinite(np.asarray(x)).all() for x in leaves)
        assert all(np.isfinite(v) for v in observer.parameters().values())
        # it reads these people better than a uniform guess: the NLL of their guesses under
        # its logits of the points each row's participants saw (float64 NumPy)
        nll = uniform = 0.0
        for i, (t, seen) in enumerate(zip(people.answer_trajectory, people.seen(), strict=True)):
            m = people.goal_mask[t]
            z = np.asarray(observer.prefix(people.xyz[t], people.goals[t], m, int(seen)),
                           np.float64)[m]  # fmt: skip
            c = people.counts[i][m]
            nll -= float(c @ (z - np.logaddexp.reduce(z)))
            uniform += float(c.sum() * np.log(m.sum()))
        assert np.isfinite(nll) and nll < uniform, (nll, uniform)

        # ---- plan: a held-out scene's goal, the prefix objective at the study's τ
        split = tiny_data["position_test"]
        k = int(np.argmax(split.goal_mask.sum(1) >= 3))
        goals, mask, target = split.goals[k], split.goal_mask[k], int(split.target[k])
        cfg = planning.PlannerConfig(n_points=20, iters=8, taus=TAUS)
        planner = planning.make_planner(observer, cfg)
        res = planner(goals[None], mask[None], np.array([target]))
        straight = planner.straight_line(goals[None], mask[None], np.array([target]))
        d = res.diagnostics
        assert bool(res.feasible[0]) and float(d.cost[0]) <= float(d.cost_limit[0]) + 1e-6
        # the objective, re-derived: mean over τ of log softmax(prefix at L_τ)[target]

        def prefix_legibility(xyz):
            out = []
            for seen in cfg.seen():
                z = np.asarray(observer.prefix(xyz, goals, mask, seen), np.float64)[mask]
                out.append(z[mask[:target].sum()] - np.logaddexp.reduce(z))
            return float(np.mean(out))

        best = prefix_legibility(np.asarray(res.xyz[0]))
        np.testing.assert_allclose(best, float(d.objective[0, d.best_iter[0]]), atol=1e-4)
        # the learned observer reads the plan earlier than the straight line
        assert int(d.best_iter[0]) > 0 and best > prefix_legibility(np.asarray(straight.xyz[0]))
        q = np.asarray(res.q[0], np.float32)
        with render.MotionRenderer((32, 32)) as r:  # MuJoCo C's forward kinematics
            tcp = r.tcp_path(q)
        np.testing.assert_allclose(tcp, np.asarray(res.xyz[0]), atol=1e-4)
        assert np.linalg.norm(tcp[-1] - goals[target]) <= planning.MAX_RESIDUAL
        plans = tmp_path / "plans.npz"
        np.savez(plans, names=np.array(["straight", "people"]), goals=goals[None],
                 goal_mask=mask[None], target=np.array([target], np.int32),
                 q=np.stack([np.asarray(straight.q), q[None]]).astype(np.float32),
                 xyz=np.stack([np.asarray(straight.xyz), np.asarray(res.xyz)]).astype(
                     np.float32))  # fmt: skip
        stacked = {"straight-0": np.asarray(straight.q[0]), "people-0": q}

        # ---- evaluate: the plans as the next round of the running study
        run(study_cli.main, "stimuli", "--plans", plans, "--n", 2, "--taus",
            ",".join(map(str, TAUS)), "--attention", 0, "--no-practice", "--next-round",
            stim)  # fmt: skip
        assert stimuli.find_rounds(stim) == [0, 1]
        st1 = stimuli.load_stimulus_set(stim / "round-1")
        assert {s["trajectory"] for s in st1.manifest["stimuli"]} == set(stacked)
        np.testing.assert_allclose(np.array(st1.trajectories["people-0"])[:, 1:],
                                   np.asarray(res.xyz[0]), rtol=1e-5, atol=1e-6)  # fmt: skip
        # a new participant gets the plans' stimuli: the still served is the picture of its
        # motion at τ (PNG: the same pixels as a fresh rendering), not of the other one
        shown: list[tuple[dict, bytes]] = []

        def look(state, still):
            shown.append((state, still))
            return state["goals"][0]

        probe, _ = asyncio.run(client.run_participant(
            server.url, look, ids={"PROLIFIC_PID": "probe"}, timeout=120))  # fmt: skip
        assert probe.code is not None and len(shown) == 2
        by_sha = {s["still_sha256"]: s for s in st1.manifest["stimuli"]}
        size = tuple(st1.manifest["size"])
        with render.MotionRenderer(size) as r:
            for _, still in shown:
                s = by_sha[hashlib.sha256(still).hexdigest()]  # a round-1 stimulus
                served = np.asarray(Image.open(io.BytesIO(still)).convert("RGB"), float)
                err = {
                    name: np.abs(served - render.still(
                        qk, goals, mask, tau=s["tau"], size=size, labels=s["goals"],
                        renderer=r)).mean()
                    for name, qk in stacked.items()
                }  # fmt: skip
                own = err.pop(s["trajectory"])
                assert own < 1e-3 and own < min(err.values()), (s["trajectory"], own, err)

        # fresh people of the population answer the evaluation round
        run(study_cli.main, "simulate", "--url", server.url, "--stimuli", stim,
            "--participants", EVAL, "--population", "default", "--seed", 1,
            "--first", FIRST)  # fmt: skip
        assert f"{EVAL} of {EVAL} simulated participants finished, {2 * EVAL} answers" in (
            capsys.readouterr().out
        )
    finally:
        server.stop()
    rows = stored(db)
    assert rows[: len(rows0)] == rows0  # round 0's answers, unchanged
    later = rows[len(rows0) :]
    assert [r[7] for r in later if r[0] == "probe"] == [s["goals"][0] for s, _ in shown]
    crowd = [r for r in later if r[0] != "probe"]
    assert len(crowd) == 2 * EVAL and {r[0] for r in crowd} == {
        f"sim-{i}" for i in range(FIRST, FIRST + EVAL)}  # fmt: skip
    assert all(r[1] == 1 and r[6] == "trial" for r in later)
    got = {e: [r[7] for r in crowd if r[0] == e] for e in dict.fromkeys(r[0] for r in crowd)}
    assert got == replayed(stim, crowd, seed=1)
    # each participant saw both motions, one τ each; the stimuli got balanced answers
    for e in got:
        assert sorted(r[4] for r in crowd if r[0] == e) == sorted(stacked)
    per = Counter((r[4], r[5]) for r in later)  # the probe's too
    assert {t for t, _ in per} == set(stacked) and max(per.values()) - min(per.values()) <= 1


def test_next_round_and_later_crowd_refuse_bad_input(tmp_path, capsys):
    """``stimuli --next-round`` and ``simulate --first``: one line ``error: ...`` naming
    the flag, before any work (nothing rendered, no round written)."""
    q, xyz, goals, mask, target = motions(4, seed=1)
    plans = {}
    for name, shift in (("old", 0.0), ("new", 0.01)):  # the same ids, other motions
        plans[name] = tmp_path / f"{name}.npz"
        np.savez(plans[name], names=np.array(["a"]), goals=goals[:3], goal_mask=mask[:3],
                 target=target[:3], q=q[None, :3], xyz=xyz[None, :3] + shift)  # fmt: skip
    stim = tmp_path / "stim"
    make_stimuli.make_set(make_stimuli.motions_from_plans(plans["old"]), stim, n=2,
                          taus=(0.5,), attention=0, practice=False, renderer=DotRenderer(),
                          progress=False)  # fmt: skip
    (tmp_path / "empty").mkdir()
    nxt = ["stimuli", "--plans", plans["new"], "--n", 1, "--taus", "0.5", "--attention", 0,
           "--no-practice", "--next-round"]  # fmt: skip
    cases = [
        ([*nxt, stim, "--size", "64x48"], "--size: --next-round keeps round 0's clip settings"),
        ([*nxt, stim, "--hold", "0"], "--hold: --next-round keeps round 0's clip settings"),
        ([*nxt, stim, "--overwrite"], "--overwrite: --next-round writes a new round"),
        ([*nxt, tmp_path / "empty"], f"--next-round {tmp_path / 'empty'}: no study folder"),
        ([*nxt, stim], f"--plans {plans['new']}: trajectory 'a-0' is another motion than the "
                       f"one of that id in round 0 of {stim}"),
        (["simulate", "--stimuli", stim, "--first", -1], "--first -1: expected an integer >= 0"),
    ]  # fmt: skip
    for argv, msg in cases:
        with pytest.raises(SystemExit) as e:
            study_cli.main([str(a) for a in argv])
        err = capsys.readouterr().err.strip().splitlines()
        assert e.value.code == 2 and len(err) == 1 and err[0].startswith(f"error: {msg}"), err
    assert stimuli.find_rounds(stim) == [0] and not (stim / "round-1").exists()
    # the same motions under the same ids pass the check
    make_stimuli.check_ids_across_rounds(stim, make_stimuli.motions_from_plans(plans["old"]),
                                         "--plans")  # fmt: skip
