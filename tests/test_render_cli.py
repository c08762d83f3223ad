"""``python -m slotv_jax.render`` (run in-process): every source, and errors before rendering."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from slotv_jax import data, execution, render, study
from slotv_jax.render import cli
from slotv_jax.rendering import compare, overlay
from slotv_jax.rendering import frames as frames_lib
from slotv_jax.robot import kinematics

SIZE = (64, 48)
FAST = ["--size", "64x48", "--fps", "5", "--duration", "1", "--hold", "0.2", "--quiet"]
GOALS = np.zeros((8, 3), np.float32)
GOALS[:3] = [[0.45, -0.25, 0.025], [0.55, 0.0, 0.025], [0.40, 0.25, 0.025]]
MASK = np.arange(8) < 3


def _path(end, n=10):
    a = np.linspace(0, 1, n)[:, None]
    return ((1 - a) * kinematics.Q_HOME + a * np.asarray(end)).astype(np.float32)


Q1 = _path([0.3, -0.2, 0.1, -2.0, 0.05, 1.9, 0.7])
Q2 = _path([-0.3, 0.1, 0.0, -2.2, 0.0, 2.2, 0.8])


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """A two-trajectory position_test split written by data.save_split."""
    out = tmp_path_factory.mktemp("data")
    q = np.stack([Q1, Q2])
    with render.MotionRenderer(SIZE) as r:
        xyz = np.stack([r.tcp_path(qi) for qi in q]).astype(np.float32)
    y = np.where(MASK, 1 / 3, 0).astype(np.float32)
    split = data.Split(
        name="position_test",
        xyz=xyz,
        q=q,
        target=np.array([1, 2], np.int32),
        env_id=np.zeros(2, np.int32),
        n_via=np.ones(2, np.int32),
        residual=np.zeros(2, np.float32),
        scene_goals=GOALS[None],
        scene_mask=MASK[None],
        labels={n: np.stack([y, y]) for n in data.LABELER_NAMES},
        meta={},
    )
    data.save_split(out, split, data.DataConfig(preset="tiny", n_train=2, n_eval=2))
    return out


def test_a_dataset_trajectory_to_mp4(dataset, tmp_path):
    out = tmp_path / "a.mp4"
    args = ["--data", str(dataset), "--split", "position_test", "--index", "1", "--out", str(out)]
    assert cli.main([*args, *FAST]) == 0
    clip = render.read_video(out)
    assert clip.shape == (6 + 1, SIZE[1], SIZE[0], 3)  # 0, 0.2, ..., 1 and one held frame
    kw = {"size": SIZE, "fps": 5, "duration": 1, "hold": 0.2}
    err = [np.abs(clip.astype(int) - render.motion_frames(q, GOALS, MASK, **kw)) for q in (Q2, Q1)]
    assert err[0].mean() < 8.0  # H.264 in 4:2:0 at 64x48 is lossy (about 6 levels of 255)
    assert err[0][-1].mean() < 0.7 * err[1][-1].mean()  # trajectory 1 drawn, not 0


def test_several_trajectories_into_a_folder(dataset, tmp_path):
    args = ["--data", str(dataset), "--split", "position_test", "--index", "0:2", "--tau", "0.5"]
    assert cli.main([*args, "--out", str(tmp_path / "stills"), "--format", "png", *FAST]) == 0
    for i, q in enumerate((Q1, Q2)):
        got = render.read_video(tmp_path / "stills" / f"position_test_{i:04d}.png")[0]
        np.testing.assert_array_equal(got, render.still(q, GOALS, MASK, tau=0.5, size=SIZE))


def test_a_preset_name_renders_the_main_jobs_dataset(dataset, tmp_path, monkeypatch):
    """``--data quick`` reads the dataset the main job cached, data/quick-<digest>."""
    monkeypatch.chdir(tmp_path)
    home = data.preset_dir("quick")
    home.mkdir(parents=True)
    for f in ("position_test.npz", "position_test.json"):
        (home / f).write_bytes((dataset / f).read_bytes())
    args = ["--data", "quick", "--split", "position_test", "--index", "1", "--out", "b.png"]
    assert cli.main([*args, *FAST]) == 0
    got = render.read_video(tmp_path / "b.png")[0]
    np.testing.assert_array_equal(got, render.still(Q2, GOALS, MASK, size=SIZE))


def test_plans_side_by_side_and_one_planner(tmp_path):
    plans = tmp_path / "plans.npz"
    np.savez(
        plans,
        goals=np.stack([GOALS, GOALS]),
        goal_mask=np.stack([MASK, MASK]),
        target=np.array([0, 1]),
        family=np.array(["dragan", "dragan"]),
        names=np.array(["straight", "oracle"]),
        q=np.stack([np.stack([Q1, Q2]), np.stack([Q2, Q1])]),
        xyz=np.zeros((2, 2, 10, 3), np.float32),
    )
    both = tmp_path / "both.png"
    assert cli.main(["--plans", str(plans), "--problem", "1", "--out", str(both), *FAST]) == 0
    img = render.read_video(both)[0]
    assert img.shape[1] == 2 * SIZE[0] + compare.GAP
    one = tmp_path / "one.png"
    args = ["--plans", str(plans), "--problem", "1", "--planner", "oracle", "--out", str(one)]
    assert cli.main([*args, *FAST]) == 0
    right = img[:, SIZE[0] + compare.GAP :]
    np.testing.assert_array_equal(render.read_video(one)[0][:, :, :3], right)  # same panel
    swapped = tmp_path / "swapped.png"
    args = ["--plans", str(plans), "--problem", "1", "--planner", "oracle,straight"]
    assert cli.main([*args, "--out", str(swapped), *FAST]) == 0
    np.testing.assert_array_equal(render.read_video(swapped)[0][:, : SIZE[0]], right)


def test_a_study_file_through_ik_with_goal_names(tmp_path):
    with render.MotionRenderer(SIZE) as r:
        xyz = r.tcp_path(Q1)[None].astype(np.float32)
    names = np.array(["cup", "box", "pen", "", "", "", "", ""])
    st = study.make_study(xyz, GOALS, MASK, np.array([0]), np.eye(8)[None, 1], goal_names=names)
    study.save_study(tmp_path / "s.npz", st)
    out = tmp_path / "s.png"
    args = ["--study", str(tmp_path / "s.npz"), "--labels", "names", "--out", str(out)]
    assert cli.main([*args, *FAST]) == 0
    got = render.read_video(out)[0]
    want = render.still(Q1, GOALS, MASK, size=SIZE, labels=["cup", "box", "pen"])
    assert np.abs(got.astype(int) - want).mean() < 1.0  # the IK's joints draw the same picture


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--camera", "ceiling"], "--camera: expected one of"),
        (["--tau", "0"], "tau: expected a normalised time in (0, 1]"),
        (["--tau", "1.5"], "tau: expected"),
        (["--size", "10x10"], "--size: expected WxH"),
        (["--index", "7"], "--index 7: expected indices in 0..1"),
        (["--split", "nope"], "--split: expected one of"),
        (["--out", "/proc/a.mp4"], "--out /proc/a.mp4: cannot write in /proc"),
        (["--out", "a.avi"], "expected a file ending in .mp4 or .gif or .png"),
        (
            ["--labels", "names"],
            "position_test_0000 has no goal names (only a --study file "
            "has them); use --labels letters",
        ),
        (
            ["--data", "data/quick"],
            "data/quick: no such dataset folder (TMP/data/quick); give the preset name alone "
            "(quick) for the dataset the main job made; to make a dataset in this folder, run: "
            "python -m slotv_jax.data --preset quick --out data/quick",
        ),
        (
            ["--data", "quick"],
            "dataset 'quick': the quick preset's dataset is not in TMP/data/quick-",
        ),
        (["--index", "0:2", "--out", "x.mp4"], "2 items need a folder"),
    ],
)
def test_bad_input_is_one_line_before_rendering(
    dataset, tmp_path, monkeypatch, capsys, args, message
):
    def boom(*a, **k):
        raise AssertionError("rendering started before the input was checked")

    monkeypatch.setattr(frames_lib.MotionRenderer, "__init__", boom)
    monkeypatch.chdir(tmp_path)
    base = {"--data": str(dataset), "--split": "position_test", "--out": "a.mp4"}
    for k, v in zip(args[::2], args[1::2], strict=True):
        base[k] = v
    with pytest.raises(SystemExit) as e:
        cli.main([*(x for kv in base.items() for x in kv), "--quiet"])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    message = message.replace("TMP", str(tmp_path))  # the folder it ran in
    assert len(err) == 1 and err[0].startswith("error: ") and message in err[0], err


def test_nan_joints_in_an_npz_are_named(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(frames_lib.MotionRenderer, "__init__", None)  # must not be reached
    q = np.stack([Q1, Q2])
    q[1, 4, 2] = np.nan
    np.savez(tmp_path / "t.npz", xyz=np.zeros((2, 10, 3)), goals=GOALS, goal_mask=MASK, q=q)
    with pytest.raises(SystemExit):
        cli.main(["--npz", str(tmp_path / "t.npz"), "--index", "0:2", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert err.startswith("error: t_0001: q: expected finite values"), err


def test_plans_grid_rows_and_panels(tmp_path):
    """--grid: one row per problem (default: the families in turn), the same panels in each
    (planners with a non-finite plan in any chosen problem left out, unless named)."""
    plans = tmp_path / "plans.npz"
    np.savez(
        plans,
        goals=np.stack([GOALS] * 3),
        goal_mask=np.stack([MASK] * 3),
        target=np.array([0, 1, 2]),
        family=np.array(["dragan", "dragan", "nikolaidis"]),
        names=np.array(["straight", "oracle", "slotv", "archetype"]),
        q=np.stack([np.stack([Q1, Q2, Q1])] * 3 + [np.stack([Q1, Q2, np.full_like(Q1, np.nan)])]),
    )
    assert cli.grid_problems(np.array(["dragan", "dragan", "nikolaidis"])) == [0]  # no 2nd n
    assert cli.grid_problems(np.array(["d"] * 4 + ["n"] * 4)) == [0, 5, 2]
    assert cli.grid_problems(np.array(["d"] * 4 + ["n"] * 4), n=2) == [0, 5]
    bar = overlay.title(np.zeros((48, 64, 3), np.uint8), "x").shape[0]
    base = ["--plans", str(plans), "--grid", "--size", "64x48", "--quiet"]
    cases = (
        ([], 1, 4),  # problem 0 (the families in turn)
        (["--problem", "0,2"], 2, 3),  # archetype is NaN in problem 2: left out of both rows
        (["--problem", "0,1"], 2, 4),  # every planner finite in 0 and 1
        (["--problem", "1", "--planner", "oracle,slotv"], 1, 2),
    )
    for i, (extra, rows, panels) in enumerate(cases):
        out = tmp_path / f"fig_{i}.png"
        assert cli.main([*base, *extra, "--out", str(out)]) == 0
        img = render.read_video(out)[0]
        assert img.shape[:2] == (
            rows * (2 * bar + 48) + (rows - 1) * compare.GAP,
            panels * 64 + (panels - 1) * compare.GAP,
        ), extra


@pytest.mark.parametrize(
    "args, message",
    [
        (["--out", "x.mp4"], "--grid: expected a .png"),
        (["--out", "x.png", "--sheet", "2"], "--grid: expected a .png --out and no --sheet"),
    ],
)
def test_plans_grid_refuses_other_outputs(tmp_path, monkeypatch, capsys, args, message):
    monkeypatch.setattr(frames_lib.MotionRenderer, "__init__", None)  # must not be reached
    plans = tmp_path / "plans.npz"
    np.savez(plans, goals=GOALS[None], goal_mask=MASK[None], target=np.array([0]),
             names=np.array(["straight"]), q=np.stack([Q1])[None])  # fmt: skip
    with pytest.raises(SystemExit):
        cli.main(["--plans", str(plans), "--grid", *args])
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err


def test_plans_a_problem_nobody_planned_or_too_many_planners(tmp_path, monkeypatch, capsys):
    """A problem whose every plan is NaN, a grid with no planner in all its rows, nine
    planners side by side (``qs: expected 1..8 motions, got 0``, once rendering had begun):
    one line naming the file, the array and the flag that picks another, before rendering."""
    monkeypatch.setattr(frames_lib.MotionRenderer, "__init__", None)  # must not be reached
    plans = tmp_path / "plans.npz"
    q = np.stack([np.stack([Q1, Q2])] * 9)
    q[:, 1] = np.nan  # nobody planned problem 1
    np.savez(plans, goals=np.stack([GOALS] * 2), goal_mask=np.stack([MASK] * 2),
             target=np.array([0, 1]), names=np.array([f"p{k}" for k in range(9)]), q=q)  # fmt: skip
    where = f"error: --plans {plans}: "
    for args, message in (
        (["--problem", "1"], "q: no planner has a plan of problem 1 (each row holds NaN); "
                             "choose another --problem"),
        (["--problem", "0,1", "--grid"], "q: no planner has a plan of every problem of the "
                                         "grid (0, 1); choose others with --problem"),
        (["--problem", "0"], "names: 9 planners of problem 0, at most 8 side by side; name at "
                             "most 8 with --planner"),
    ):  # fmt: skip
        with pytest.raises(SystemExit) as e:
            cli.main(["--plans", str(plans), *args, "--out", str(tmp_path / "x.png"), "--quiet"])
        err = capsys.readouterr().err
        assert e.value.code == 2 and err == where + message + "\n", err
    assert not (tmp_path / "x.png").exists()


def test_a_recorded_plan_at_the_robot_s_speed(tmp_path, monkeypatch, capsys):
    """--timed: the clip lasts as long as the Panda's motion (slotv_jax.execution), and each
    frame is the planned motion where the robot is at that moment: the untimed clip's frame
    at the path fraction the robot has reached."""
    plans = "experiments/planning_paper_plans.npz"
    q = np.load(plans)["q"][0, 0]
    traj = execution.time_plan(q)
    out = tmp_path / "timed.mp4"
    fast = ["--size", "128x96", "--fps", "5", "--hold", "0", "--quiet"]
    args = ["--plans", plans, "--problem", "0", "--planner", "straight", "--timed"]
    assert cli.main([*args, *fast, "--out", str(out)]) == 0
    clip = render.read_video(out)
    t = np.arange(len(clip)) / 5
    assert len(clip) == int(np.ceil(5 * traj.duration - 1e-9)) + 1 and t[-2] < traj.duration

    def untimed(tau):  # the same panel, the plan's points evenly in time, stopped at tau
        png = tmp_path / f"still_{tau:.6f}.png"
        assert cli.main([*args[:6], "--tau", repr(tau), *fast, "--out", str(png)]) == 0
        return render.read_video(png)[0][..., :3].astype(int)

    # each frame: the path fraction reached at t_k (knot times -> i / 99), not t_k / T; seen
    # where the two differ most (the robot starts slowly and brakes late)
    tau = np.interp(t[:-1], traj.knot_times, np.linspace(0, 1, len(q)))
    for k in np.argsort(np.abs(tau - t[:-1] / t[-1]))[-2:]:
        right, even = (np.abs(clip[k] - untimed(float(x))).mean() for x in (tau[k], t[k] / t[-1]))
        assert right < 8.0 and right < 0.7 * even, (k, right, even)  # H.264 is lossy
    assert np.abs(clip[-1] - untimed(1.0)).mean() < 8.0
    monkeypatch.setattr(frames_lib.MotionRenderer, "__init__", None)  # errors come first
    for extra, message in ((["--duration", "2"], "--duration: --timed plays"),
                           (["--speed", "0"], "--speed: expected")):  # fmt: skip
        with pytest.raises(SystemExit):
            cli.main([*args, *fast, *extra, "--out", str(tmp_path / "x.mp4")])
        assert message in capsys.readouterr().err
    untimed_args = [a for a in args if a != "--timed"]
    for flag in (["--speed", "0.5"], ["--robot", "fr3"]):  # they time nothing without --timed
        with pytest.raises(SystemExit):
            cli.main([*untimed_args, *fast, *flag, "--out", str(tmp_path / "x.mp4")])
        assert f"error: {flag[0]}: only with --timed" in capsys.readouterr().err
    with pytest.raises(SystemExit):  # two planners side by side: not one motion
        cli.main([*args[:4], "--timed", *fast, "--out", str(tmp_path / "y.mp4")])
    assert "a timed clip shows one" in capsys.readouterr().err


def test_no_opengl_is_one_line_naming_mujoco_gl(dataset, tmp_path):
    """A real backend failure: GLFW with no display (as on a headless machine)."""
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    env["MUJOCO_GL"] = "glfw"
    args = ["--data", str(dataset), "--split", "position_test", "--out", str(tmp_path / "a.mp4")]
    cmd = [sys.executable, "-m", "slotv_jax.render", *args]
    out = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 2, out.stderr
    errors = [line for line in out.stderr.splitlines() if line.startswith("error: ")]
    assert len(errors) == 1 and "MUJOCO_GL=glfw" in errors[0] and "libegl1" in errors[0]
    assert not (tmp_path / "a.mp4").exists()


# Prepended to a subprocess's code: no EGL library loads, as on a plain CUDA container.
# ctypes.CDLL, and the class behind ctypes.cdll through which PyOpenGL loads, refuse libEGL.
HIDE_EGL = """
import ctypes
class _NoEGL(ctypes.CDLL):
    def __init__(self, name, *args, **kwargs):
        if "libEGL" in str(name):
            raise OSError(f"{name}: cannot open shared object file: No such file or directory")
        super().__init__(name, *args, **kwargs)
ctypes.CDLL = ctypes.cdll._dlltype = _NoEGL
"""


def test_without_an_egl_library_only_rendering_fails_in_one_line(tmp_path):
    """A machine with no display and no EGL library: the package, the robot's kinematics and
    the labelers load (MuJoCo without OpenGL: MUJOCO_GL=disable, PyOpenGL's EGL
    never imported), and the render command refuses in one line that names the missing
    library and how to install it, writing nothing. (It once failed at MuJoCo's import with
    PyOpenGL's AttributeError, training and labelling too.)"""
    plans = tmp_path / "plans.npz"
    np.savez(plans, goals=GOALS[None], goal_mask=MASK[None], target=np.array([0]),
             names=np.array(["straight"]), q=np.stack([Q1])[None])  # fmt: skip
    env = {k: v for k, v in os.environ.items()
           if k not in ("DISPLAY", "WAYLAND_DISPLAY", "MUJOCO_GL")}  # fmt: skip
    code = HIDE_EGL + (
        "import os, sys\n"
        "from slotv_jax import labelers\n"
        "from slotv_jax.robot import kinematics\n"
        "import mujoco\n"
        "m = kinematics.mj_model()\n"
        "mujoco.mj_forward(m, mujoco.MjData(m))\n"
        "print(os.environ.get('MUJOCO_GL'), 'OpenGL.EGL' in sys.modules, flush=True)\n"
        "from slotv_jax.render import cli\n"
        "cli.main(sys.argv[1:])\n"
    )
    out_file = tmp_path / "a.mp4"
    args = ["--plans", str(plans), "--out", str(out_file), *FAST]
    out = subprocess.run([sys.executable, "-c", code, *args], env=env, capture_output=True,
                         text=True, timeout=120)  # fmt: skip
    assert out.stdout.split() == ["disable", "False"], out.stderr[-3000:]
    assert out.returncode == 2, out.stderr[-3000:]
    err = out.stderr.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: cannot render: "), err
    assert "no EGL library (libEGL.so.1)" in err[0], err
    assert "apt-get install libegl1 libgl1-mesa-dri" in err[0] and "NVIDIA" in err[0], err
    assert not out_file.exists()


def test_egl_is_chosen_without_a_display_whatever_imports_mujoco_first():
    """Without a display and MUJOCO_GL, importing any module that loads MuJoCo first (the
    data room, as `study next` does) still leaves it on EGL: the choice is the package's."""
    env = {k: v for k, v in os.environ.items()
           if k not in ("DISPLAY", "WAYLAND_DISPLAY", "MUJOCO_GL")}  # fmt: skip
    code = ("import os, sys, slotv_jax.data; "
            "print(os.environ.get('MUJOCO_GL'), 'mujoco' in sys.modules)")  # fmt: skip
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         timeout=120)  # fmt: skip
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["egl", "True"]


PLANS = "experiments/planning_paper_plans.npz"


@pytest.mark.parametrize(
    "args, message",
    [
        (["--duration", "1e9"], "--duration 1e+09: a clip of 30000000031 frames at 30 fps"),
        (["--hold", "1e9"], "--hold 1e+09: a clip of 30000000091 frames (30000000000 of them"),
        (["--fps", "1e9"], "--fps 1e+09: expected frames per second in (0, 240]"),
        (["--duration", "1e4", "--size", "16x16"], "--duration 10000: a clip of 300031 frames"),
        (["--size", "4096x4096", "--duration", "30"], "--size 4096x4096: 931 frames take 43.6 GiB"),
    ],
)
def test_a_clip_too_long_or_too_fast_is_refused_before_anything_is_loaded(
    tmp_path, monkeypatch, capsys, args, message
):
    """The issue's clips (a 224 GiB traceback, a machine's memory): one line naming the flag,
    before the plans are even read; the counts are those of the frames the clip would have
    (30 fps, 1 s held: ceil(duration * 30) + 1 + hold * 30)."""
    monkeypatch.setattr(cli, "load_plans", lambda *a: pytest.fail("loaded before the check"))
    monkeypatch.setattr(frames_lib.MotionRenderer, "__init__", None)
    with pytest.raises(SystemExit) as e:
        cli.main(["--plans", PLANS, "--problem", "2", *args, "--out", str(tmp_path / "x.gif")])
    err = capsys.readouterr().err.strip().splitlines()
    assert e.value.code == 2 and len(err) == 1 and err[0] == f"error: {err[0][7:]}", err
    assert message in err[0], err
    assert not (tmp_path / "x.gif").exists()


def test_check_clip_counts_the_frames_of_the_clip():
    """check_clip's count is the length of the clip's frame times (the frames rendered), its
    bytes every panel's, and each bound holds at its limit and fails just past it."""
    for tau, fps, duration, hold in ((0.5, 5, 1, 0.2), (1.0, 30, 3, 1), (0.37, 24, 2.5, 0)):
        n = len(frames_lib.frame_times(tau, fps=fps, duration=duration, hold=hold))
        assert frames_lib.check_clip(SIZE, fps=fps, duration=duration, hold=hold, tau=tau) == n
    top = frames_lib.MAX_CLIP_FRAMES
    assert frames_lib.check_clip(SIZE, fps=30, duration=(top - 1) / 30, hold=0) == top
    with pytest.raises(ValueError, match=f"duration .*: a clip of {top + 1} frames"):
        frames_lib.check_clip(SIZE, fps=30, duration=top / 30, hold=0)
    with pytest.raises(ValueError, match="fps 241: expected"):
        frames_lib.check_clip(SIZE, fps=241, duration=1, hold=0)
    side = 4096 * 4096 * 3  # bytes of one frame: 256 of them are 12 GiB, 85 are < 4 GiB
    n = frames_lib.MAX_CLIP_BYTES // side
    assert frames_lib.check_clip((4096, 4096), fps=1, duration=n - 1, hold=0) == n
    with pytest.raises(ValueError, match=f"size 4096x4096: {n} frames of 2 panels"):
        frames_lib.check_clip((4096, 4096), fps=1, duration=n - 1, hold=0, panels=2)
    assert frames_lib.CLIP_BOUNDS in " ".join(cli._parser().format_help().split())  # --help


def test_side_by_side_panels_and_a_timed_motion_count_too(tmp_path, monkeypatch, capsys):
    """The bytes of 7 planners side by side (refused before the renderer opens), and the
    length of a motion at the robot's speed, known once it is timed."""
    monkeypatch.setattr(frames_lib.MotionRenderer, "__init__", None)
    base = ["--plans", PLANS, "--problem", "2", "--out", str(tmp_path / "x.gif")]
    with pytest.raises(SystemExit) as e:
        cli.main([*base, "--size", "1920x1080", "--duration", "10"])
    err = capsys.readouterr().err.strip().splitlines()
    want = "error: --size 1920x1080: 331 frames of 7 panels take 13.4 GiB"
    assert e.value.code == 2 and len(err) == 1 and err[0].startswith(want), err
    args = cli._parser().parse_args([*base, "--timed", "--speed", "1e-4"])
    item = cli.Item("slow", (Q1,), GOALS, MASK, 0, t=np.linspace(0, 6745.5, 10), duration=6745.5)
    speed = execution.TimingConfig(speed=1e-4)
    with pytest.raises(ValueError, match=r"--timed: slow lasts 6746 s at --speed 0\.0001: "
                       r"duration 6745\.5: a clip of 202396 frames"):  # fmt: skip
        cli._check_clip(args, (640, 360), item, speed)


def test_seven_planners_lie_in_a_grid_with_the_target_marked(tmp_path):
    """Every planner of a plans file side by side: seven panels in rows of three (not one
    row seven panels wide), the empty cells white, and the target marked without being
    asked (the same picture as with --mark-target)."""
    names = ["straight", "oracle", "slotv", "trex", "slotv_plus", "trex_plus", "archetype"]
    plans = tmp_path / "plans.npz"
    np.savez(plans, goals=GOALS[None], goal_mask=MASK[None], target=np.array([2]),
             family=np.array(["dragan"]), names=np.array(names),
             q=np.stack([(Q1 if k % 2 else Q2)[None] for k in range(7)]),
             xyz=np.zeros((7, 1, 10, 3), np.float32))  # fmt: skip
    out, marked = tmp_path / "all.png", tmp_path / "marked.png"
    assert cli.main(["--plans", str(plans), "--problem", "0", "--out", str(out), *FAST]) == 0
    args = ["--plans", str(plans), "--problem", "0", "--mark-target", "--out", str(marked)]
    assert cli.main([*args, *FAST]) == 0
    img = render.read_video(out)[0][:, :, :3]
    panel = render.read_video(tmp_path / "all.png")[0].shape
    assert compare.side_columns(7) == 3
    assert img.shape[1] == 3 * SIZE[0] + 2 * compare.GAP
    h = (img.shape[0] - 2 * compare.GAP) / 3  # three rows of equal height
    assert h == int(h) and h > SIZE[1], panel
    assert (img[-int(h) :, -SIZE[0] :] == 255).all()  # the two cells after the seventh: white
    np.testing.assert_array_equal(img, render.read_video(marked)[0][:, :, :3])
