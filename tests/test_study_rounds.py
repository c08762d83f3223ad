"""study next (slotv_jax.study.rounds): train on the answers of round 0, write round 1 as
a valid stimulus set."""

import csv
import json
import sqlite3
from pathlib import Path

import numpy as np
import pytest
from docs_pages import commands, marked_block
from study_fixtures import DotRenderer, ServerProcess, motions, write_dot_set

from slotv_jax import data, render
from slotv_jax.answers.storage import load_study
from slotv_jax.core import opengl
from slotv_jax.execution import cli as execution_cli
from slotv_jax.observers import population
from slotv_jax.planning import plans as plans_lib
from slotv_jax.study import cli as study_cli
from slotv_jax.study import rounds
from slotv_jax.training import config as train_config
from slotv_jax.webstudy import database, make_stimuli, stimuli


def _candidates(n=12):
    q, xyz, goals, mask, target = motions(n, seed=5)
    ids = [f"cand{i}" for i in range(n)]
    return make_stimuli.Motions(q, xyz, goals, mask, ids, ids, target, np.full(n, 6), None)


def _guess(goals, k, p):
    """Participant p's guess at trial stimulus k: p 0 and 1 agree, p 2 guesses the next goal."""
    return goals[(k + p // 2) % len(goals)]


def _answer_round0(stimdir, out):
    """Answers to round 0's trial stimuli (each guessed by 3 people), in the export format."""
    m = json.loads((stimdir / stimuli.MANIFEST).read_text())
    rows = []
    for k, s in enumerate(x for x in m["stimuli"] if x["kind"] == "trial"):
        for p in range(3):
            rows.append([s["trajectory"], s["tau"], _guess(s["goals"], k, p),
                         f"p{p}", s["camera"]])  # fmt: skip
    out.mkdir()
    with open(out / "answers.csv", "w", newline="") as f:
        csv.writer(f).writerows([["trajectory", "tau", "guess", "participant", "condition"],
                                 *rows])  # fmt: skip
    answered = {r[0] for r in rows}
    for name in ("trajectories.csv", "goals.csv"):  # the answered trajectories, as exported
        with open(stimdir / name, newline="") as f:
            table = list(csv.reader(f))
        with open(out / name, "w", newline="") as f:
            csv.writer(f).writerows([table[0], *(r for r in table[1:] if r[0] in answered)])


def _answer_in_db(stimdir, path):
    """The answers of :func:`_answer_round0`, given through the server's database (3
    participants, each shown every stimulus of round 0)."""
    st = stimuli.load_stimulus_set(stimdir)
    trial_ids = [s["id"] for s in st.manifest["stimuli"] if s["kind"] == "trial"]
    db = database.connect(path)
    db.load_round(0, st.manifest, st.trajectories, st.goals)
    for p in range(3):
        pid = db.create_participant(f"sha{p}", {}, lambda s, c, seed: [x.key for x in s], p, "C")
        for t in db.trials(pid):
            if t["kind"] == "trial":
                guess = _guess(t["goals"], trial_ids.index(t["id"]), p)
                db.answer(pid, t["position"], guess, None, 1.0)
    db.close()


def _rows(study):
    """{(trajectory id, τ): guesses per goal name} of a study's answer rows."""
    out = {}
    for i, n in enumerate(study.answer_trajectory):
        names = study.goal_names[n][study.goal_mask[n]].tolist()
        key = (study.trajectory_ids[n], round(float(study.answer_tau[i]), 6))
        out[key] = dict(zip(names, study.counts[i][: len(names)].tolist(), strict=True))
    return out


def test_next_round_is_a_valid_stimulus_set(tmp_path):
    stimdir, answers = tmp_path / "study", tmp_path / "answers"
    write_dot_set(stimdir, n=4)
    _answer_round0(stimdir, answers)
    got = rounds.read_answers(answers)
    assert got.n_answers == 4 * 2 * 3 and got.n_trajectories == 4
    # study next --db: the server's database gives the answers its export gives
    _answer_in_db(stimdir, tmp_path / "study.db")
    from_db = rounds.read_answers(db=tmp_path / "study.db")
    assert _rows(from_db) == _rows(got) and sorted(_rows(got)[("m0", 0.5)].values())[-1] == 2
    cand = _candidates()
    cfg = train_config.quick("slotv", hidden=(8, 4), batch_size=4, train_size=None)
    shown = rounds.shown_stimuli(stimdir)
    assert ("m0", 0.5) in shown
    choice = rounds.choose(got, cand, n=3, taus=(0.5, 1.0), cfg=cfg, members=2,
                               updates=10, exclude={("cand0", 0.5)}, seed=1)  # fmt: skip
    assert len(choice["picks"]) == 3 and len(set(choice["picks"])) == 3
    assert (0, 0.5) not in choice["picks"] and choice["candidates"] == 23
    again = rounds.choose(got, cand, n=3, taus=(0.5, 1.0), cfg=cfg, members=2,
                              updates=10, exclude={("cand0", 0.5)}, seed=1)  # fmt: skip
    assert again["picks"] == choice["picks"]  # deterministic
    ep = rounds.choose(got, cand, n=3, taus=(0.5, 1.0), cfg=cfg, members=2, updates=10,
                       strategy="epig", seed=1)  # fmt: skip
    # the recorded scores are the picks' own EPIG (the targets it picked with), best first
    assert ep["score"] == "epig" and len(set(ep["picks"])) == 3
    assert ep["scores"] == sorted(ep["scores"], reverse=True) and min(ep["scores"]) >= 0
    r, _ = rounds.write_round(
        stimdir, cand, choice["picks"], renderer=DotRenderer(), attention=1,
        source={"kind": "active", **{k: v for k, v in choice.items() if k != "picks"}},
        progress=False,
    )  # fmt: skip
    assert r == 1 and stimuli.find_rounds(stimdir) == [0, 1]
    loaded = stimuli.load_stimulus_set(stimdir / "round-1", verify=True)  # checksums, tables
    assert loaded.round == 1 and loaded.manifest["source"]["strategy"] == "margin"
    trials = [(s["trajectory"], s["tau"]) for s in loaded.manifest["stimuli"]
              if s["kind"] == "trial"]  # fmt: skip
    assert sorted(trials) == sorted((cand.ids[i], t) for i, t in choice["picks"])
    kinds = [s["kind"] for s in loaded.manifest["stimuli"]]
    assert kinds.count("attention") == 1 and kinds.count("practice") == 1
    # round 1's trials are excluded from the next choice
    assert set(trials) <= rounds.shown_stimuli(stimdir)


def test_next_rejects_bad_input(tmp_path, capsys):
    with pytest.raises(ValueError, match="missing"):
        rounds.read_answers(tmp_path)
    with pytest.raises(ValueError, match="give one"):
        rounds.read_answers()
    argv = ["next", "--stimuli", str(tmp_path / "nothing"), "--answers", str(tmp_path),
            "--data", str(tmp_path)]  # fmt: skip
    with pytest.raises(SystemExit) as e:
        study_cli.main(argv)
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: --stimuli")


def test_next_refuses_round_0_s_clips_past_the_bounds_before_training(
    tmp_path, monkeypatch, capsys
):
    """A round 0 whose clips are past rendering.frames.check_clip's bounds (an edited
    manifest): `study next` refuses in one line before reading the answers, not after the
    ensemble's training."""
    write_dot_set(tmp_path / "study", n=2)
    path = tmp_path / "study" / stimuli.MANIFEST
    manifest = json.loads(path.read_text())
    path.write_text(json.dumps({**manifest, "duration": 1e9}))
    monkeypatch.setattr(rounds, "read_answers", None)  # must not be reached
    argv = ["next", "--stimuli", str(tmp_path / "study"), "--answers", str(tmp_path),
            "--data", str(tmp_path)]  # fmt: skip
    with pytest.raises(SystemExit) as e:
        study_cli.main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    want = f"error: --stimuli {tmp_path / 'study'}: round 0's clips: duration 1e+09: a clip of "
    assert e.value.code == 2 and len(err) == 1 and err[0].startswith(want), err


def test_next_without_egl_refuses_before_training(tmp_path, monkeypatch, capsys):
    """Headless with no EGL library, `study next` (which renders the round last, after the
    ensemble's training) refuses in one line before reading the answers."""
    write_dot_set(tmp_path / "study", n=2)
    for k in ("DISPLAY", "WAYLAND_DISPLAY"):
        monkeypatch.delenv(k, raising=False)
    monkeypatch.setenv("MUJOCO_GL", "egl")
    monkeypatch.setattr(opengl, "egl_library", lambda: None)
    monkeypatch.setattr(rounds, "read_answers", None)  # must not be reached
    argv = ["next", "--stimuli", str(tmp_path / "study"), "--answers", str(tmp_path),
            "--data", str(tmp_path)]  # fmt: skip
    with pytest.raises(SystemExit) as e:
        study_cli.main(argv)
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: cannot render: ") and "libegl1" in err[0]


def _plans_of(study, path, names=("straight", "dragan", "pool"), shift=0.0):
    """A pick's plans file of two of ``study``'s scenes (every planner a straight line to
    the target, joints zero): what ``study pick --by plans`` writes, made by hand."""
    goals = np.asarray(study.goals[:2], np.float32) + np.float32(shift)
    mask, target = study.goal_mask[:2], np.array([0, 1])
    start = np.array([0.3, 0.0, 0.5], np.float32)
    s = np.linspace(0, 1, 6, dtype=np.float32)[None, :, None]
    xyz = start + s * (goals[np.arange(2), target][:, None] - start)
    k = len(names)
    np.savez(path, q=np.zeros((k, 2, 6, 7), np.float32), xyz=np.stack([xyz] * k),
             goals=np.where(mask[..., None], goals, 0), goal_mask=mask, target=target,
             names=np.array(names))  # fmt: skip
    return path


def test_a_round_of_plans_asks_about_every_planner_of_the_study_s_own_scenes(tmp_path, capsys):
    """``study next --plans``: the candidates are a pick's plans of the study's own scenes,
    each planner asked about in turn (the best of each by the strategy's score), their ids
    new for the round; a plans file of another study's scenes, a study with no answers, a
    round size ≤ 0 or past ``--budget`` are refused in one line before any training."""
    stimdir, answers = tmp_path / "study", tmp_path / "answers"
    write_dot_set(stimdir, n=4)
    _answer_round0(stimdir, answers)
    got = rounds.read_answers(answers)
    plans = _plans_of(got, tmp_path / "plans.npz")
    cand, groups = rounds.plans_round(plans, got, 1)
    assert cand.ids == [f"r1-{p}-{j}" for p in ("straight", "dragan", "pool") for j in (0, 1)]
    assert groups == ["straight"] * 2 + ["dragan"] * 2 + ["pool"] * 2
    cfg = train_config.quick("slotv", hidden=(8, 4), batch_size=4, train_size=None)
    choice = rounds.choose(got, cand, n=4, taus=(0.5, 1.0), cfg=cfg, members=2, updates=10,
                           seed=1, groups=groups)  # fmt: skip
    asked = [groups[i] for i, _ in choice["picks"]]
    assert asked[:3] == ["straight", "dragan", "pool"] and len(set(choice["picks"])) == 4
    with pytest.raises(ValueError, match="another study"):
        rounds.plans_round(_plans_of(got, tmp_path / "other.npz", shift=0.05), got, 1)
    empty = got.select_rows(np.zeros(got.n_rows, bool))
    with pytest.raises(ValueError, match="no answers yet"):
        rounds.choose(empty, cand, n=1, taus=(1.0,), cfg=cfg, members=2, updates=1)
    base = ["next", "--stimuli", str(stimdir), "--answers", str(answers), "--no-progress"]
    bad = {
        "another study": ["--plans", str(tmp_path / "other.npz")],
        "--n 0": ["--plans", str(plans), "--n", "0"],
        "exceed --budget 9": ["--plans", str(plans), "--n", "2", "--budget", "9"],
    }
    for says, extra in bad.items():
        with pytest.raises(SystemExit) as e:
            study_cli.main([*base, *extra])
        err = capsys.readouterr().err.strip().splitlines()
        assert e.value.code == 2 and len(err) == 1 and says in err[0], (says, err)
    assert stimuli.find_rounds(stimdir) == [0]  # nothing written
    # and a round of plans written: round 1's trials are plans, every planner among them
    ok = [*base, "--plans", str(plans), "--n", "3", "--members", "2", "--updates", "10",
          "--attention", "0", "--no-practice", "--budget", "11"]  # fmt: skip
    assert study_cli.main(ok) == 0
    m1 = stimuli.load_stimulus_set(stimdir / "round-1").manifest
    trials = [s["trajectory"] for s in m1["stimuli"] if s["kind"] == "trial"]
    assert {t.split("-")[1] for t in trials} == {"straight", "dragan", "pool"}
    assert m1["source"]["plans"] == str(plans) and "round 1" in capsys.readouterr().out


# ------------------------------------------------- two rounds, as the manual walks them


#: What the walk adds to the manual's commands, to run in a test's time: smaller clips, two
#: hand-crafted candidates (each fitted in a second), two folds and two problems, a
#: two-member ensemble and no checks in round 1, and the people of a population file who
#: watched from the lab's camera (the manual's ``default`` people watch from the scene's).
WALK_EXTRA = {
    "stimuli": ["--size", "64x48", "--fps", "4", "--duration", "1", "--hold", "0"],
    "simulate": ["--population", "lab_people.json"],
    "pick": "--candidates dragan,nikolaidis --problems 2 --folds 2 --no-progress".split(),
    # two problems' plans (the manual's pick plans 12) leave too few motions for checks
    "next": "--members 2 --updates 10 --attention 0 --no-practice --no-progress".split(),
}


def _walk_people(path, camera: str) -> None:
    """The default population, every person watching from ``camera`` (a camera file)."""
    doc = population.get_population("default").to_dict()
    doc.update(name="lab people", viewpoints={camera: 1.0})
    path.write_text(json.dumps(doc))


@pytest.mark.slow  # two picks that plan, two rounds rendered and answered over HTTP
def test_two_rounds_walk_from_the_lab_s_camera_to_the_robot(
    tiny_data, tiny_cfg, tmp_path, monkeypatch, capsys
):
    """The manual's two-round study (docs/guides/study.md, ``two-rounds``), each command as
    a shell runs it (its own parser and checks), in the manual's order: stimuli from the
    lab's camera file, people through the running server, export, import, a pick that plans
    the study's scenes, a round of those plans, people again, export and import of both
    rounds, the pick on every answer, and its plan written for the robot. Each step is
    checked against what the step before it stored."""
    home = data.dataset_dir(tmp_path / data.DEFAULT_CACHE, data.quick())
    home.mkdir(parents=True)
    data.save_split(home, tiny_data["trajectory_test"], tiny_cfg)
    monkeypatch.chdir(tmp_path)
    block = commands(marked_block("docs/guides/study.md", "two-rounds", "bash"))
    ran: list[str] = []
    server = None
    try:
        for argv, body in block:
            if argv[0] == "cat":  # cat > FILE <<'EOF'
                assert argv[1] == ">" and body is not None
                Path(argv[2]).write_text(body)
                _walk_people(tmp_path / "lab_people.json", str(tmp_path / argv[2]))
                continue
            if argv in (["server=$!"], ["kill", "$server"]):
                if argv[0] == "kill":
                    server.stop()
                    server = None
                continue
            module, sub, *args = argv[2:]
            ran.append(f"{module} {sub}")
            if sub == "serve":
                i = args.index("--stimuli"), args.index("--db")
                server = ServerProcess(Path(args[i[0] + 1]), Path(args[i[1] + 1]))
                continue
            args = [server.url if a == "http://127.0.0.1:8765" else a for a in args]
            main = execution_cli.main if module == "slotv_jax.execution" else study_cli.main
            assert main([sub, *args, *WALK_EXTRA.get(sub, [])]) == 0, (sub, args)
            out = capsys.readouterr().out
            if sub == "simulate":
                assert "12 of 12 simulated participants finished" in out, out
    finally:
        if server is not None:
            server.stop()
    assert ran == [
        "slotv_jax.study stimuli", "slotv_jax.study serve", "slotv_jax.study simulate",
        "slotv_jax.study export", "slotv_jax.study import", "slotv_jax.study pick",
        "slotv_jax.study next", "slotv_jax.study simulate", "slotv_jax.study export",
        "slotv_jax.study import", "slotv_jax.study pick", "slotv_jax.execution export",
    ]  # fmt: skip
    cam = json.loads((tmp_path / "lab_cam.json").read_text())
    # round 0 and round 1 were filmed from the lab's camera, its pose kept in each manifest
    m0 = stimuli.load_stimulus_set(tmp_path / "lab_stim").manifest
    m1 = stimuli.load_stimulus_set(tmp_path / "lab_stim" / "round-1").manifest
    for m in (m0, m1):
        assert {s["camera"] for s in m["stimuli"]} == {"lab_cam"}
        np.testing.assert_allclose(m["cameras"]["lab_cam"]["position"], cam["position"])
        assert m["cameras"]["lab_cam"]["fovy"] == pytest.approx(cam["fovy"])
    assert rounds.trial_count(tmp_path / "lab_stim") == 8 + 6  # the budget, exactly
    # round 1 asked about the first pick's plans, of round 0's scenes, every planner in turn
    plans1 = plans_lib.load_plans(tmp_path / "lab_pick1" / "plans.npz")
    trials1 = [s for s in m1["stimuli"] if s["kind"] == "trial"]
    assert all(s["trajectory"].startswith("r1-") for s in trials1)
    asked = {s["trajectory"].split("-")[1] for s in trials1}
    assert asked == set(plans1["names"]), (asked, plans1["names"])
    # the second import holds every answer of both rounds, as the database stored them
    s0, s1 = load_study(tmp_path / "lab_study0.npz"), load_study(tmp_path / "lab_study1.npz")
    con = sqlite3.connect(tmp_path / "lab_study.db")
    per_round = dict(con.execute(
        "SELECT s.round, COUNT(*) FROM answers a JOIN trials t ON t.trial = a.trial JOIN "
        "stimuli s ON s.stimulus = t.stimulus WHERE s.kind = 'trial' GROUP BY s.round"
    ).fetchall())  # fmt: skip
    con.close()
    assert set(per_round) == {0, 1} and all(n > 0 for n in per_round.values())
    assert s0.n_answers == per_round[0] and s1.n_answers == per_round[0] + per_round[1]
    assert {t for t in s1.trajectory_ids if t.startswith("r1-")} == {
        s["trajectory"] for s in trials1}  # fmt: skip
    # the second pick chose on both rounds' answers, and its pool's plan reached the robot:
    # the written joint path starts and ends where the plan does, within the Panda's limits
    pool = json.loads((tmp_path / "lab_pick2" / "pool.json").read_text())
    assert pool["meta"]["study"] == "lab_study1.npz" and pool["meta"]["camera"] == "lab_cam.json"
    plans2 = plans_lib.load_plans(tmp_path / "lab_pick2" / "plans.npz")
    k = list(plans2["names"]).index("pool")
    q_plan = np.asarray(plans2["q"][k, 0], np.float64)
    table = np.loadtxt(tmp_path / "lab_plan.csv", delimiter=",", skiprows=1)
    t, q = table[:, 0], table[:, 1:8]
    assert t[0] == 0 and np.all(np.diff(t) > 0)
    np.testing.assert_allclose(q[0], q_plan[0], atol=1e-6)
    np.testing.assert_allclose(q[-1], q_plan[-1], atol=1e-6)
    with render.MotionRenderer((32, 32)) as r:  # MuJoCo C's forward kinematics
        tcp = r.tcp_path(q[-1:].astype(np.float32))
    goal = plans2["goals"][0][plans2["target"][0]]
    assert np.linalg.norm(tcp[-1] - goal) < 0.01, (tcp[-1], goal)
