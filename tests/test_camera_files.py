"""The lab's own camera, as a camera file: read and checked, drawn, projected, and taken by
the labelers, archetypes, populations, stimuli, pools and commands."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys

import numpy as np
import pytest
from study_fixtures import robot_motions

from slotv_jax import labelers, rendering, scene
from slotv_jax.observers import archetypes, parametric, population
from slotv_jax.rendering.camera import named_camera
from slotv_jax.webstudy import make_stimuli, stimuli

SIZE = (320, 180)


def _write(path, **fields) -> str:
    path.write_text(json.dumps(fields))
    return str(path)


def _as_file(tmp_path, name: str, stem: str = "lab") -> str:
    """A camera file with the pose and field of view of the scene's camera ``name``."""
    c = named_camera(name)
    return _write(tmp_path / f"{stem}.json", position=c.pos.tolist(), rotation=c.rot.tolist(),
                  fovy=float(c.fovy))  # fmt: skip


def _scene3():
    goals = np.zeros((8, 3))
    goals[:3] = [[0.40, 0.20, 0.025], [0.60, -0.20, 0.025], [0.50, 0.00, 0.025]]
    return goals, np.arange(8) < 3


def test_a_camera_file_of_a_scene_camera_draws_what_that_camera_draws(tmp_path):
    """The same pose and field of view, through the OpenGL camera the file sets: the frames
    of a motion equal the named camera's, pixel for pixel up to one level of rounding."""
    q = robot_motions(1, seed=1)[0][0]
    goals, mask = _scene3()
    kw = dict(tau=1.0, size=SIZE, fps=4, duration=1, hold=0)
    for name in ("observer_angle", "observer_side"):
        a = rendering.motion_frames(q, goals, mask, camera=name, **kw)
        b = rendering.motion_frames(q, goals, mask, camera=_as_file(tmp_path, name), **kw)
        diff = np.abs(a.astype(int) - b)
        assert diff.max() <= 1 and (diff > 0).mean() < 1e-3, (name, diff.max())


def test_a_camera_file_s_own_pose_and_field_of_view_project_onto_its_picture(tmp_path):
    """A camera no scene camera resembles (elsewhere, 25° and 60°, 4:3): each cube's centre,
    projected by the one projection of the project, lands on that cube in MuJoCo's
    segmentation image of the file's camera (an independent check of the drawn frustum)."""
    goals, mask = _scene3()
    r = rendering.MotionRenderer((320, 240))
    try:
        for fovy in (25.0, 60.0):
            cam = _write(tmp_path / f"c{fovy:g}.json", position=[1.3, -0.9, 1.1],
                         look_at=[0.5, 0.0, 0.1], fovy=fovy, resolution=[640, 480])  # fmt: skip
            r.set_goals(goals, mask)
            seg = r.frame(np.zeros(7), cam, segmentation=True)
            px, depth = rendering.pixels(goals[:3], cam, (320, 240))
            assert np.all(depth > 0)
            cube_geoms = {int(seg[int(y), int(x), 0]) for x, y in px}
            assert len(cube_geoms) == 3, (fovy, px)  # three different objects, one per cube
            for (x, y), g in zip(px, goals[:3], strict=True):
                gid = int(seg[int(y), int(x), 0])
                pos = r.data.geom_xpos[gid]
                assert np.linalg.norm(pos - g) < 0.03, (fovy, pos, g)
    finally:
        r.close()


def test_the_labelers_populations_and_archetypes_take_a_camera_file(tmp_path):
    """Nikolaidis' labeler, a population that watches from a camera and the viewpoint
    archetype's start give with a camera file what they give with the scene camera of the
    same pose."""
    path = _as_file(tmp_path, "observer_angle")
    _, xyz, goals, mask, _ = robot_motions(2, seed=2)
    for i in range(2):
        a = labelers.nikolaidis(xyz[i], goals[i], mask[i], "observer_angle")
        b = labelers.nikolaidis(xyz[i], goals[i], mask[i], path)
        np.testing.assert_allclose(np.asarray(b), np.asarray(a), atol=2e-6)
    pop = population.default()
    named = dataclasses.replace(pop, viewpoints=(("observer_angle", 1.0),))
    filed = dataclasses.replace(pop, viewpoints=((path, 1.0),))
    population.Population.from_dict(filed.to_dict())  # the file passes the population's checks
    T = xyz.shape[1]
    p_named = population.population_probs(population.quadrature(named), xyz[0], goals[0],
                                          mask[0], T)  # fmt: skip
    p_filed = population.population_probs(population.quadrature(filed), xyz[0], goals[0],
                                          mask[0], T)  # fmt: skip
    np.testing.assert_allclose(np.asarray(p_filed), np.asarray(p_named), atol=2e-6)
    m = archetypes.make_archetype("viewpoint", camera=path)
    want = parametric.camera_pose(scene.camera("observer_angle"))
    got = [m.parameters()[k] for k in ("yaw", "pitch", "distance")]
    np.testing.assert_allclose(got, want, atol=1e-5)


BAD = [
    ({"position": [1, 0, 1], "rotation": [[1, 0, 0], [0, 1, 0], [0, 0.5, 1]], "fovy": 40},
     "orthonormal"),
    ({"position": [1, 0, 1], "rotation": [[-1, 0, 0], [0, 1, 0], [0, 0, 1]], "fovy": 40},
     "right-handed"),
    ({"position": [1, 0, 1], "look_at": [0, 0, 0], "fovy": 0}, "'fovy'"),
    ({"position": [1, 0, 1], "look_at": [0, 0, 0], "fovy": 180}, "'fovy'"),
    ({"position": [1, 0, 1], "look_at": [0, 0, 0], "fovy": "40"}, "'fovy'"),
    ({"position": [1, 0, 1], "fovy": 40}, "exactly one of"),
    ({"position": [1, 0], "look_at": [0, 0, 0], "fovy": 40}, "'position'"),
    ({"position": [1, 0, 1], "look_at": [1, 0, 1], "fovy": 40}, "'look_at'"),
    ({"position": [0, 0, 2], "look_at": [0, 0, 0], "fovy": 40}, "'up'"),
    ({"position": [1, 0, 1], "look_at": [0, 0, 0], "fov": 40}, "'fov'"),
    ({"position": [1, 0, 1], "look_at": [0, 0, 0], "fovy": 40, "resolution": [0, 9]},
     "'resolution'"),
]  # fmt: skip


@pytest.mark.parametrize(("fields", "says"), BAD)
def test_a_bad_camera_file_is_refused_naming_its_field(tmp_path, fields, says):
    path = _write(tmp_path / "bad.json", **fields)
    with pytest.raises(ValueError, match=says) as e:
        scene.check_camera(path)
    assert path in str(e.value) and "\n" not in str(e.value)


def test_cameras_that_are_no_file_or_see_no_goal_are_refused(tmp_path):
    (tmp_path / "notjson.json").write_text("{position")
    with pytest.raises(ValueError, match="JSON"):
        scene.check_camera(str(tmp_path / "notjson.json"))
    with pytest.raises(ValueError, match="no camera file"):
        scene.check_camera(str(tmp_path / "missing.json"))
    with pytest.raises(ValueError, match="no camera named"):
        scene.check_camera("observr")
    goals, mask = _scene3()
    away = _write(tmp_path / "away.json", position=[1.6, 0, 0.8], look_at=[3, 0, 0.8], fovy=40)
    with pytest.raises(ValueError, match="sees none of the goals"):
        scene.check_sees_goals(away, goals, mask)
    scene.check_sees_goals(_as_file(tmp_path, "observer"), goals, mask)  # sees them


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", *args], capture_output=True, text=True,
                          timeout=300)  # fmt: skip


def test_the_commands_refuse_a_bad_camera_file_in_one_line_before_any_work(tmp_path):
    """``study stimuli``, ``render``, the labelers' command and ``study pick`` read the camera
    file first: one line
    naming the flag and the field; nothing written."""
    bad = _write(tmp_path / "bad.json", position=[1, 0, 1], look_at=[0, 0, 0], fovy=200)
    out = tmp_path / "out"
    cmds = {
        "--cameras": ("slotv_jax.study", "stimuli", "--data", str(tmp_path / "nodata"),
                      "--cameras", f"observer,{bad}", "--out", str(out)),
        "--camera": ("slotv_jax.render", "--npz", str(tmp_path / "no.npz"), "--camera", bad,
                     "--out", str(out / "x.mp4")),
        "labelers --camera": ("slotv_jax.labelers", "--in", str(tmp_path / "no.npz"),
                              "--camera", bad, "--out", str(out / "y.npz")),
    }  # fmt: skip
    for flag, cmd in cmds.items():
        flag = flag.split()[-1]
        p = _run(*cmd)
        err = p.stderr.strip().splitlines()
        assert p.returncode == 2 and len(err) == 1, (cmd, p.stderr)
        assert flag in err[0] and "'fovy'" in err[0], err
        assert not out.exists()
    p = _run("slotv_jax.data", "--preset", "quick", "--camera", bad, "--out", str(out))
    assert p.returncode == 2 and "python -m slotv_jax.labelers --camera" in p.stderr
    assert not out.exists()
    p = _run("slotv_jax.study", "pick", str(tmp_path / "no.npz"), "--camera", bad, "--out",
             str(out))  # fmt: skip
    assert p.returncode == 2 and "--camera" in p.stderr and "'fovy'" in p.stderr, p.stderr


def test_stimuli_from_a_camera_file_name_it_and_keep_its_pose(tmp_path):
    """Stimuli filmed by a camera file: ids and the answers' ``condition`` carry its stem, the
    manifest keeps its pose and field of view (the file may move or change later), two
    cameras of one stem are refused, and a camera that sees none of the scenes' goals is
    refused before any clip is rendered."""
    lab = _as_file(tmp_path, "observer_side", stem="lab_side")
    q, xyz, goals, mask, target = robot_motions(2, seed=4)
    m = make_stimuli.Motions(q=q, xyz=xyz, goals=goals, goal_mask=mask, targets=target,
                             ids=["m0", "m1"], scenes=["s0", "s1"], t=None,
                             length=np.full(2, q.shape[1]))  # fmt: skip
    r = make_stimuli.SceneRenderer((96, 64), 4.0, 0.5, 0.0)
    try:
        man = make_stimuli.make_set(m, tmp_path / "stim", n=2, taus=(1.0,), cameras=(lab,),
                                    attention=0, practice=False, renderer=r,
                                    progress=False)  # fmt: skip
        assert {s["camera"] for s in man["stimuli"]} == {"lab_side"}
        assert all(s["id"].endswith("_lab_side") for s in man["stimuli"])
        rec = man["cameras"]["lab_side"]
        c = named_camera("observer_side")
        np.testing.assert_allclose(rec["position"], c.pos, atol=1e-6)
        np.testing.assert_allclose(rec["rotation"], c.rot, atol=1e-6)
        assert rec["fovy"] == pytest.approx(float(c.fovy)) and rec["file"] == lab
        stimuli.load_stimulus_set(tmp_path / "stim")  # a valid set
        twin = tmp_path / "other"
        twin.mkdir()
        twin_lab = _as_file(twin, "observer", stem="lab_side")
        with pytest.raises(ValueError, match="share the label"):
            make_stimuli.make_set(m, tmp_path / "s2", n=2, taus=(1.0,), cameras=(lab, twin_lab),
                                  attention=0, practice=False, renderer=r,
                                  progress=False)  # fmt: skip
        away = _write(tmp_path / "away.json", position=[1.6, 0, 0.8], look_at=[3, 0, 0.8],
                      fovy=40)  # fmt: skip
        with pytest.raises(ValueError, match=r"--cameras: .*sees none of the goals"):
            make_stimuli.make_set(m, tmp_path / "s3", n=2, taus=(1.0,), cameras=(away,),
                                  attention=0, practice=False, renderer=r,
                                  progress=False)  # fmt: skip
        assert not (tmp_path / "s2").exists() and not (tmp_path / "s3").exists()
    finally:
        r.close()
