"""Stimulus sets rendered from each source: clips cut at τ, manifest, tables, checksums."""

from __future__ import annotations

import json

import numpy as np
import pytest
from study_fixtures import robot_motions

from slotv_jax import execution, render, study
from slotv_jax.webstudy import make_stimuli, stimuli
from slotv_jax.webstudy.database import SQLiteStorage
from slotv_jax.webstudy.service import StudyService

SIZE, FPS, DURATION, HOLD = (160, 96), 10.0, 1.0, 0.2


@pytest.fixture(scope="module")
def renderer():
    r = make_stimuli.SceneRenderer(SIZE, FPS, DURATION, HOLD)
    yield r
    r.close()


@pytest.fixture(scope="module")
def motions():
    return robot_motions(4, seed=3)


def test_plans_source_clips_end_at_tau(renderer, motions, tmp_path):
    """A planning run's plans (2 planners x 2 problems, one NaN plan left out): each clip
    has the frames of its τ and ends on the frame at τ, not later; the manifest and the
    tables hold what the arrays say; a second set refuses the folder without --overwrite."""
    q, xyz, goals, mask, target = motions
    plans = tmp_path / "plans.npz"
    qk = np.stack([q[:2], q[2:]])  # (K=2, P=2, T, 7)
    xk = np.stack([xyz[:2], xyz[2:]])
    qk[1, 1] = np.nan  # planner b failed on problem 1
    np.savez(plans, q=qk, xyz=xk, goals=goals[:2], goal_mask=mask[:2], target=target[:2],
             names=np.array(["a", "b"]))  # fmt: skip
    m = make_stimuli.motions_from_plans(plans)
    assert m.ids == ["a-0", "a-1", "b-0"] and m.scenes == ["problem0", "problem1", "problem0"]
    np.testing.assert_array_equal(m.goals[2], goals[0])
    man = make_stimuli.make_set(m, tmp_path / "stim", n=2, taus=(0.5,), attention=1,
                                practice=False, renderer=renderer, progress=False)  # fmt: skip
    st = stimuli.load_stimulus_set(tmp_path / "stim")  # verifies files and checksums
    assert [s["kind"] for s in man["stimuli"]] == ["trial", "trial", "attention"]
    for s in man["stimuli"]:
        i = m.ids.index(s["trajectory"])
        clip = render.read_video(st.file(s, "clip"))
        n = len(render.frame_times(s["tau"], fps=FPS, duration=DURATION, hold=HOLD))
        assert clip.shape == (n, SIZE[1], SIZE[0], 3)
        # the last frame is the motion at τ: closer to it than to any later time
        later = [t for t in (s["tau"], s["tau"] + 0.2, s["tau"] + 0.4, 1.0) if t <= 1.0]
        err = [np.abs(clip[-1].astype(float) - render.still(
            m.q[i], m.goals[i], m.goal_mask[i], tau=t, size=SIZE, labels=s["goals"],
            renderer=renderer.renderer)).mean() for t in dict.fromkeys(later)]  # fmt: skip
        assert np.argmin(err) == 0 and err[0] < 4.0, err  # H.264 is lossy
        assert s["target"] == s["goals"][m.targets[i]]
        # the goal labels' pixel positions are inside the picture
        px = np.array(s["goal_pixels"])
        assert ((px >= 0) & (px <= SIZE)).all()
    pts = st.trajectories["a-0"]
    np.testing.assert_allclose(np.array(pts)[:, 1:], m.xyz[0], atol=1e-6)
    assert [row[0] for row in st.goals["a-0"]] == ["A", "B", "C"]
    # one attention motion: study.json records the one attention trial a participant gets
    recorded = json.loads((tmp_path / "stim" / "study.json").read_text())["attention_checks"]
    service = StudyService(tmp_path / "stim", SQLiteStorage(tmp_path / "study.db"))
    p = service.participant(service.start({}, None))
    kinds = [t["kind"] for t in service.storage.trials(p["participant"])]
    assert recorded == kinds.count("attention") == 1
    with pytest.raises(ValueError, match="overwrite"):
        make_stimuli.make_set(m, tmp_path / "stim", n=1, taus=(1.0,), attention=0,
                              renderer=renderer, progress=False)  # fmt: skip
    # the next round goes into round-1, drawn like round 0
    assert stimuli.next_round(tmp_path / "stim") == (1, tmp_path / "stim" / "round-1")
    like = make_stimuli.SceneRenderer.like(tmp_path / "stim")
    assert like.settings() == renderer.settings() == {k: man[k] for k in like.settings()}
    like.close()


def test_npz_and_study_sources_by_ik(renderer, motions, tmp_path):
    """Paths without joints (a labelers .npz, a study file) get them by IK, and a set of a
    study file (no targets) needs --attention 0."""
    _, xyz, goals, mask, target = motions
    np.savez(tmp_path / "labels_in.npz", xyz=xyz, goals=goals, goal_mask=mask, target=target)
    m = make_stimuli.motions_from_npz(tmp_path / "labels_in.npz")
    assert m.ids[0] == "labels_in-0" and list(m.targets) == list(target)
    for i in range(4):  # joints that put the TCP on the path (the arm is redundant)
        np.testing.assert_allclose(renderer.renderer.tcp_path(m.q[i]), xyz[i], atol=2e-3)
    s = study.make_study(xyz, goals, mask, np.arange(4), np.eye(8)[target],
                         trajectory_ids=["w", "x", "y", "z"])  # fmt: skip
    study.save_study(tmp_path / "s.npz", s)
    m = make_stimuli.motions_from_study(tmp_path / "s.npz")
    assert m.ids == ["w", "x", "y", "z"] and m.targets is None
    with pytest.raises(ValueError, match="no targets"):
        make_stimuli.make_set(m, tmp_path / "st", n=1, taus=(1.0,), renderer=renderer)
    man = make_stimuli.make_set(m, tmp_path / "st", n=2, taus=(0.5, 1.0), attention=0,
                                renderer=renderer, progress=False)  # fmt: skip
    assert len(man["stimuli"]) == 5 and man["stimuli"][-1]["kind"] == "practice"


def test_trials_per_participant_is_written_and_an_edited_study_json_kept(
    renderer, motions, tmp_path, capsys
):
    """``trials`` (``stimuli --trials K``) sets study.json's trials_per_participant: in a new
    folder over the defaults, in a replaced set field by field, keeping what a researcher
    edited; a K above --n or on a later round is refused before anything is rendered."""
    _, xyz, goals, mask, target = motions
    np.savez(tmp_path / "m.npz", xyz=xyz, goals=goals, goal_mask=mask, target=target)
    m = make_stimuli.motions_from_npz(tmp_path / "m.npz")
    kw = {"taus": (1.0,), "attention": 0, "practice": False, "renderer": renderer,
          "progress": False}  # fmt: skip
    out = tmp_path / "stim"
    make_stimuli.make_set(m, out, n=2, trials=1, **kw)
    got = json.loads((out / "study.json").read_text())
    assert got == {**stimuli.SETTINGS, "trials_per_participant": 1, "attention_checks": 0}
    (out / "study.json").write_text(json.dumps({**got, "title": "Mine"}))
    make_stimuli.make_set(m, out, n=2, trials=2, overwrite=True, **kw)
    assert stimuli.read_settings(out)["trials_per_participant"] == 2
    assert stimuli.read_settings(out)["title"] == "Mine"
    make_stimuli.make_set(m, out, n=2, overwrite=True, **kw)  # no --trials: the file's
    assert stimuli.read_settings(out)["trials_per_participant"] == 2
    before = sorted(p.name for p in tmp_path.iterdir())
    with pytest.raises(ValueError, match=r"--trials 3: expected 1\.\.2"):
        make_stimuli.make_set(m, tmp_path / "new", n=2, trials=3, **kw)
    with pytest.raises(ValueError, match=r"round 1 keeps round 0's study\.json"):
        make_stimuli.make_set(m, out / "round-1", n=1, trials=1, round_=1, **kw)
    (out / "study.json").write_text(json.dumps({"attention_checks": -1}))  # a broken edit
    with pytest.raises(ValueError, match="field 'attention_checks'"):
        make_stimuli.make_set(m, out, n=2, trials=1, overwrite=True, **kw)
    assert sorted(p.name for p in tmp_path.iterdir()) == before
    assert not (out / "round-1").exists()
    assert json.loads((out / "study.json").read_text()) == {"attention_checks": -1}
    # the command: --next-round keeps the study's settings; a K of 0 is refused; one line each
    from slotv_jax.study import cli as study_cli

    src = ["stimuli", "--npz", str(tmp_path / "m.npz"), "--n", "1", "--attention", "0"]
    for argv, msg in (
        ([*src, "--next-round", str(out), "--trials", "1"], "--trials: --next-round keeps"),
        ([*src, "--out", str(tmp_path / "new"), "--trials", "0"], "--trials 0: expected 1..1"),
        ([*src, "--out", str(tmp_path / "new"), "--speed", "0.5"], "--speed: only with --timed"),
        ([*src, "--out", str(tmp_path / "new"), "--robot", "fr3"], "--robot: only with --timed"),
        ([*src, "--out", str(tmp_path / "new"), "--timed", "--speed", "2"], "--speed: expected"),
    ):
        with pytest.raises(SystemExit) as e:
            study_cli.main(argv)
        err = capsys.readouterr().err.strip().splitlines()
        assert e.value.code != 0 and len(err) == 1 and msg in err[0], err
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_timed_stimuli_move_at_the_robot_s_speed(tmp_path, monkeypatch):
    """--timed: each clip lasts as long as the Panda's motion (slotv_jax.execution) up to τ,
    the tables hold each point's time as a fraction of that duration, the manifest records
    the timing, and a later round is drawn the same way."""
    plans = "experiments/planning_paper_plans.npz"
    m = make_stimuli.motions_from_plans(plans)
    timing = make_stimuli.robot_timing(0.3)
    r = make_stimuli.SceneRenderer(SIZE, 5.0, None, 0.0, timing=timing)
    try:
        man = make_stimuli.make_set(m, tmp_path / "stim", n=1, taus=(0.5, 1.0), attention=0,
                                    practice=False, renderer=r, progress=False)  # fmt: skip
    finally:
        r.close()
    assert man["timing"] == {"robot": "fer", "speed": 0.3, "limits": timing["limits"]}
    assert man["duration"] is None
    st = stimuli.load_stimulus_set(tmp_path / "stim")
    tid = man["stimuli"][0]["trajectory"]
    i = m.ids.index(tid)
    traj = execution.time_plan(m.q[i])
    t = np.array(st.trajectories[tid])[:, 0]
    np.testing.assert_allclose(t, traj.knot_times / traj.duration, atol=1e-6)  # the robot's
    assert np.abs(t - np.linspace(0, 1, len(t))).max() > 0.01  # ... not evenly in time
    for s in man["stimuli"]:
        frames = render.read_video(st.file(s, "clip"))
        assert len(frames) == len(render.frame_times(s["tau"], fps=5.0, duration=traj.duration,
                                                     hold=0.0))  # fmt: skip
    like = make_stimuli.SceneRenderer.like(tmp_path / "stim")
    assert like.timing == timing and like.duration is None
    like.close()
    from slotv_jax.study import cli as study_cli

    # a later round of the same plans (the study guide's later round, run twice) holds the same
    # ids: they are the same motions at the robot's times (refused as "another motion" when
    # the check compared the plans' even times with the round's), and a moved one is not
    make_stimuli.check_ids_across_rounds(tmp_path / "stim", m, "--plans", timing)
    moved = m._replace(xyz=m.xyz + np.float32(1e-3))
    with pytest.raises(ValueError, match=f"trajectory '{tid}' is another motion"):
        make_stimuli.check_ids_across_rounds(tmp_path / "stim", moved, "--plans", timing)
    argv = ["stimuli", "--plans", plans, "--n", "1", "--taus", "0.5,1.0", "--attention", "0",
            "--no-practice", "--next-round", str(tmp_path / "stim")]  # fmt: skip
    timed = []  # the check's robot times serve the new round: each motion is timed once

    def counting(q, cfg):
        timed.append(len(q))
        return execution.time_plan(q, cfg)

    monkeypatch.setattr(make_stimuli, "time_plan", counting)
    assert study_cli.main(argv) == 0
    later = stimuli.load_stimulus_set(tmp_path / "stim" / "round-1")
    assert later.trajectories[tid] == st.trajectories[tid]
    assert later.trajectories.keys() <= {tid} and len(timed) == 1, timed


def test_plans_without_tcp_paths_get_them_by_forward_kinematics(tmp_path):
    """A plans file holding joints only (``xyz`` is optional; the people loop's example plans
    have none): motions_from_plans computes the TCP paths by MuJoCo C's kinematics, and they
    match the planner's own (MJX) paths of the same plans; the rows are the same."""
    plans = "experiments/planning_paper_plans.npz"
    z = dict(np.load(plans))
    del z["xyz"], z["y"]
    np.savez(tmp_path / "joints_only.npz", **z)
    want = make_stimuli.motions_from_plans(plans)
    got = make_stimuli.motions_from_plans(tmp_path / "joints_only.npz")
    assert got.ids == want.ids and np.array_equal(got.q, want.q)
    np.testing.assert_allclose(got.xyz, want.xyz, atol=2e-5)  # float32 MJX against float64 C


@pytest.mark.parametrize(
    "args, message",
    [
        (["--n", "0"], "--n 0: expected an integer >= 1"),
        (["--attention", "-1"], "--attention -1: expected an integer >= 0"),
        (["--taus", "0,2"], "--taus 0,2: expected distinct normalised times in (0, 1]"),
        (["--duration", "1e9"], "--duration 1e+09: a clip of 25000000013 frames at 25 fps"),
        (["--hold", "1e9"], "--hold 1e+09: a clip of "),
        (["--fps", "1e9"], "--fps 1e+09: expected frames per second in (0, 240]"),
        (["--size", "4096x4096", "--duration", "30"], "--size 4096x4096: 763 frames take"),
    ],
)
def test_counts_and_clips_are_checked_before_any_motion_is_loaded(
    tmp_path, monkeypatch, capsys, args, message
):
    """``--n 0`` (refused after 23 s of loading and IK), a clip too long or too fast (a
    traceback after 24 s): one line naming the flag, before the source is read. (25 fps,
    0.5 s held: ceil(duration * 25) + 1 + 12 frames, the half frame rounded to even.)"""
    from slotv_jax.study import cli as study_cli

    def loaded(*a, **k):
        raise AssertionError("the source was loaded before the check")

    for name in ("motions_from_plans", "load_split", "load_plans"):
        monkeypatch.setattr(make_stimuli, name, loaded)
    monkeypatch.setattr(make_stimuli.SceneRenderer, "__init__", loaded)
    out = tmp_path / "stim"
    with pytest.raises(SystemExit) as e:
        study_cli.main(["stimuli", "--plans", "experiments/planning_paper_plans.npz", *args,
                        "--out", str(out)])  # fmt: skip
    err = capsys.readouterr().err.strip().splitlines()
    assert e.value.code == 2 and len(err) == 1 and err[0].startswith("error: "), err
    assert message in err[0], err
    assert not out.exists()


def test_a_timed_clip_too_long_is_refused_before_any_rendering(tmp_path, monkeypatch):
    """At a robot's speed a clip lasts as long as the motion: checked once every motion is
    timed, before the set is rendered (ids named, with the speed)."""
    monkeypatch.setattr(stimuli, "write_stimulus_set",
                        lambda *a, **k: pytest.fail("rendered before the check"))  # fmt: skip
    r = make_stimuli.SceneRenderer(SIZE, 25.0, None, 0.5, timing=make_stimuli.robot_timing(1e-3))
    try:
        t = np.stack([np.linspace(0, 10, 6), np.linspace(0, 900, 6)])
        r.check_times(t[:1], np.array([6]), ["ok"])  # 10 s: 251 + 12 frames
        with pytest.raises(ValueError, match=r"--timed: motion slow lasts 900 s at --speed "
                           r"0\.001: duration 900: a clip of 22513 frames"):  # fmt: skip
            r.check_times(t, np.array([6, 6]), ["ok", "slow"])
    finally:
        r.close()


def test_next_round_refuses_round_0_s_clips_past_the_bounds_before_loading(
    tmp_path, monkeypatch, capsys
):
    """--next-round renders with round 0's clip settings: past the bounds (an edited
    manifest), one line naming the folder before any motion is loaded."""
    from study_fixtures import write_dot_set

    from slotv_jax.study import cli as study_cli

    write_dot_set(tmp_path / "study", n=2)
    path = tmp_path / "study" / stimuli.MANIFEST
    path.write_text(json.dumps({**json.loads(path.read_text()), "fps": 1e9}))
    monkeypatch.setattr(make_stimuli, "motions_from_plans",
                        lambda *a: pytest.fail("loaded before the check"))  # fmt: skip
    with pytest.raises(SystemExit) as e:
        study_cli.main(["stimuli", "--plans", "experiments/planning_paper_plans.npz", "--n", "1",
                        "--next-round", str(tmp_path / "study")])  # fmt: skip
    err = capsys.readouterr().err.strip().splitlines()
    want = (f"error: --next-round {tmp_path / 'study'}: round 0's clips: fps 1e+09: expected "
            "frames per second in (0, 240]")  # fmt: skip
    assert e.value.code == 2 and err == [want], err
