"""study next (slotv_jax.study.rounds): train on the answers of round 0, write round 1 as
a valid stimulus set."""

import csv
import json

import numpy as np
import pytest
from study_fixtures import DotRenderer, motions, write_dot_set

from slotv_jax.core import opengl
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
