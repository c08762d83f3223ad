"""Tests for the motion reader (slotv_jax.observers.reader) and its prior
(slotv_jax.answers.prior): its features against a float64 NumPy re-derivation, what a
prefix reads, goal padding, finite gradients at rest, a camera that is given and never
learned; the prior's labels against the sources called one by one, a prior that never
reads the answers nor the people scored; the reader as a candidate of ``study pick`` and
of the people loop."""

from __future__ import annotations

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx

from slotv_jax.answers import pick as pick_lib
from slotv_jax.answers import prior, save_study, simulate
from slotv_jax.observers import models, people, reader, zoo
from slotv_jax.study.cli import main as study_main
from slotv_jax.training import config as train_config
from slotv_jax.training import trainer, types
from slotv_jax.world import scene

T = 60
FEATURE_TOL = 2e-5  # float32 features against the float64 re-derivation (absolute, scaled units)


def _motions(seed: int, n: int):
    """Via-point paths from the home TCP to a goal on the table, n goals of 2-6 (padded)."""
    rng = np.random.default_rng(seed)
    goals = np.zeros((n, 8, 3))
    mask = np.zeros((n, 8), bool)
    xyz = np.zeros((n, T, 3))
    for i in range(n):
        c = int(rng.integers(2, 7))
        goals[i, :c, :2] = rng.uniform([0.3, -0.45], [0.7, 0.45], (c, 2))
        goals[i, :c, 2] = 0.025
        mask[i, :c] = True
        via = rng.uniform([0.25, -0.5, 0.1], [0.7, 0.5, 0.4])
        path = np.stack([[0.3069, 0.0, 0.4869], via, goals[i, rng.integers(0, c)]])
        s = np.linspace(0, 2, T)
        k = np.minimum(s.astype(int), 1)
        xyz[i] = path[k] + (s - k)[:, None] * (path[k + 1] - path[k])
    return xyz.astype(np.float32), goals.astype(np.float32), mask


def _norm64(x):
    return np.sqrt(np.sum(x * x, -1) + reader.EPS**2)


def _features64(p, g, mask, scale):
    """One view's seven features, point by point and goal by goal, in float64."""
    n, k = p.shape[0], g.shape[0]
    w = max(1, round(reader.LAG * (n - 1)))
    p, g = p / scale, g / scale
    out = np.zeros((n, k, 7))
    for i in range(n):
        j = max(i - w, 0)
        dt = max(i - j, 1) / (n - 1)
        v = p[i] - p[j]
        u = v / _norm64(v)
        dists = [_norm64(g[kk] - p[i]) for kk in range(k)]
        near = min(d for d, m in zip(dists, mask, strict=True) if m)
        for kk in range(k):
            d = g[kk] - p[i]
            ahead = max(float(d @ u), 0.0)
            out[i, kk] = [
                dists[kk],
                _norm64(g[kk] - p[0]) - dists[kk],
                (v @ d) / (_norm64(v) * dists[kk]),
                (_norm64(g[kk] - p[j]) - dists[kk]) / dt,
                ((p[i] - p[0]) @ (g[kk] - p[0])) / (_norm64(p[i] - p[0]) * _norm64(g[kk] - p[0])),
                _norm64(d - ahead * u),
                dists[kk] - near,
            ]
    return out


def _image64(points, cam):
    rel = np.asarray(points, np.float64) - np.asarray(cam.pos, np.float64)
    pc = rel @ np.asarray(cam.rot, np.float64)
    return pc[:, :2] / (-pc[:, 2:3])


@pytest.mark.parametrize("camera", ["observer", "zoo_low_left"])
def test_features_match_a_float64_re_derivation(camera):
    cam = zoo.zoo_camera(camera) if camera.startswith("zoo") else scene.camera(camera)
    xyz, goals, mask = _motions(0, 3)
    got = np.asarray(
        jax.jit(jax.vmap(reader.reading_features, in_axes=(0, 0, 0, None, None)))(
            xyz, goals, mask, cam.pos, cam.rot
        )
    )
    assert got.shape == (3, T, 8, len(reader.FEATURES))
    for b in range(3):
        world = _features64(xyz[b].astype(np.float64), goals[b].astype(np.float64), mask[b],
                            reader.WORLD_SCALE)  # fmt: skip
        image = _features64(_image64(xyz[b], cam), _image64(goals[b], cam), mask[b],
                            reader.IMAGE_SCALE)  # fmt: skip
        want = np.concatenate([world, image], -1)
        real = mask[b]
        np.testing.assert_allclose(got[b][:, real], want[:, real], atol=FEATURE_TOL, rtol=1e-5)


def test_a_prefix_reads_only_its_points_and_padding_changes_no_real_goal():
    m = reader.MotionReader((16, 16), rngs=1)
    xyz, goals, mask = (jnp.asarray(a) for a in _motions(1, 1))
    xyz, goals, mask = xyz[0], goals[0], mask[0]
    L = 25
    moved = xyz.at[L:].add(0.2)  # what was not seen yet
    a, b = m.prefix(xyz, goals, mask, L), m.prefix(moved, goals, mask, L)
    np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    grad = jax.grad(lambda x: m.prefix(x, goals, mask, L)[0])(xyz)
    assert np.all(np.asarray(grad[L:]) == 0) and np.any(np.asarray(grad[:L]) != 0)
    # a padded slot's position changes no real goal's logit, and padded logits are −∞
    far = goals.at[~mask].set(jnp.array([5.0, -3.0, 2.0]))
    np.testing.assert_allclose(np.asarray(m(xyz, far, mask))[mask],
                               np.asarray(m(xyz, goals, mask))[mask], rtol=1e-6)  # fmt: skip
    assert np.all(np.isneginf(np.asarray(m(xyz, goals, mask))[~mask]))
    # seen weights: the plain mean at the start, a distribution over the seen points only
    w = np.asarray(reader.seen_weights(m.time_coef[...], T, L))
    np.testing.assert_allclose(w[:L], 1.0 / L, rtol=1e-6)
    assert np.all(w[L:] == 0)


def test_gradients_stay_finite_for_a_hand_at_rest():
    m = reader.MotionReader((8,), rngs=2)
    goals = jnp.zeros((8, 3)).at[0].set([0.5, 0.2, 0.025]).at[1].set([0.5, -0.2, 0.025])
    mask = jnp.arange(8) < 2
    rest = jnp.broadcast_to(jnp.array([0.5, 0.2, 0.025]), (T, 3))  # still, on goal 0
    graph, p = nnx.split(m)
    for x in (rest, jnp.zeros((T, 3))):
        g_x = jax.grad(lambda x: jax.nn.log_softmax(m(x, goals, mask)[:2])[0])(x)
        assert np.all(np.isfinite(np.asarray(g_x)))
        g_p = jax.grad(lambda p, x=x: nnx.merge(graph, p)(x, goals, mask)[0])(p)
        assert all(np.all(np.isfinite(np.asarray(v))) for v in jax.tree.leaves(g_p))


def test_the_camera_is_given_and_never_learned():
    cfg = train_config.reader("quick", train_size=None, epochs=2, hidden=(8, 8))
    cam_file = dataclasses.replace(cfg, camera="observer")
    xyz, goals, mask = _motions(3, 96)
    y = np.where(mask, np.random.default_rng(0).uniform(0.1, 1, mask.shape), 0)
    y = (y / y.sum(1, keepdims=True)).astype(np.float32)
    state, _ = trainer.train_trials(cam_file, types.make_data(xyz, goals, mask, y), [0],
                                    progress=False)  # fmt: skip
    p = jax.tree.map(lambda a: a[0], state.params)
    cam = scene.camera("observer")
    np.testing.assert_array_equal(np.asarray(p["camera_pos"][...]), np.asarray(cam.pos))
    np.testing.assert_array_equal(np.asarray(p["camera_rot"][...]), np.asarray(cam.rot))
    init = nnx.split(models.make_model(cfg, 0))[1]
    assert not np.allclose(np.asarray(p["layers"][0]["kernel"][...]),
                           np.asarray(init["layers"][0]["kernel"][...]))  # fmt: skip
    # another camera: the same weights read another image (only the image view changes)
    other = reader.with_camera(p, zoo.zoo_camera("zoo_overhead"))
    np.testing.assert_array_equal(np.asarray(p["camera_pos"][...]), np.asarray(cam.pos))
    a = models.make_model(cfg, 0)
    nnx.update(a, p)
    b = models.make_model(cfg, 0)
    nnx.update(b, other)
    x, g, m = (jnp.asarray(v[0]) for v in (xyz, goals, mask))
    assert not np.allclose(np.asarray(a(x, g, m))[m], np.asarray(b(x, g, m))[m])


def test_the_config_keeps_other_models_records_and_checks_the_camera():
    assert "camera" not in train_config.preset("quick", "slotv").to_dict()
    assert "camera" not in train_config.archetype("quick", "dragan").to_dict()
    cfg = train_config.family("paper", "reader")
    d = cfg.to_dict()
    assert d["camera"] == "observer" and d["model"] == "reader" and d["hidden"] == [128, 128]
    assert train_config.TrainConfig.from_dict(d) == cfg
    assert "start_term" not in cfg.used_dict() and "hidden" in cfg.used_dict()
    with pytest.raises(ValueError, match="camera"):
        train_config.preset("quick", "slotv", camera="top")
    with pytest.raises(ValueError, match="start_term"):
        train_config.reader("quick", start_term=True)


def test_prior_labels_are_the_mean_of_the_sources_and_leave_the_scored_people_out():
    names = [n for n, _ in prior.sources(exclude=("anchor",))]
    assert "anchor" not in names and "hesitant" in names
    assert len(names) == 4 + prior.PRIOR_DRAWS + len(zoo.MEMBERS) - 1
    draws = [int(n.split(":")[1]) for n in names if n.startswith("random:")]
    from slotv_jax.observers import population

    assert not set(draws) & set(population.SUITE_DRAWS)
    xyz, goals, mask = _motions(4, 3)
    seen = np.array([T, 20, 41], np.int32)
    srcs = prior.sources(exclude=("anchor",), draws=1)
    got = prior.prior_labels(srcs, xyz, goals, mask, seen)
    want = np.zeros_like(got)
    for _, obs in srcs:  # each source called on one row at a time
        for a in range(3):
            lp = obs.prefix(jnp.asarray(xyz[a]), jnp.asarray(goals[a]), jnp.asarray(mask[a]),
                            int(seen[a]))  # fmt: skip
            want[a] += np.asarray(jax.nn.softmax(lp), np.float64) / len(srcs)
    np.testing.assert_allclose(got, want, atol=1e-5)
    assert np.allclose(got.sum(-1), 1) and np.all(got[~mask] == 0)


def test_the_prior_of_a_study_never_reads_its_answers(tmp_path):
    xyz, goals, mask = _motions(5, 6)
    rng = np.random.default_rng(0)
    traj = np.repeat(np.arange(6), 2)
    counts = np.zeros((12, 8))
    for a, t in enumerate(traj):
        counts[a, rng.integers(0, mask[t].sum())] = 3
    study = simulate.make_study(xyz, goals, mask, traj, counts,
                                answer_tau=np.tile([0.5, 1.0], 6))  # fmt: skip
    shuffled = dataclasses.replace(study, counts=counts[rng.permutation(12)])
    a, b = prior.answered_prior(study), prior.answered_prior(shuffled)
    np.testing.assert_array_equal(a.counts, b.counts)
    np.testing.assert_array_equal(a.seen(), study.seen())
    np.testing.assert_allclose(a.counts.sum(-1), 1.0)


def test_the_reader_is_a_candidate_of_study_pick_started_from_its_prior(tmp_path, monkeypatch):
    xyz, goals, mask = _motions(6, 12)
    rng = np.random.default_rng(1)
    traj = np.repeat(np.arange(12), 2)
    counts = np.zeros((24, 8))
    for a, t in enumerate(traj):
        counts[a, rng.integers(0, mask[t].sum(), 4)] += 1
    study = simulate.make_study(xyz, goals, mask, traj, counts,
                                answer_tau=np.tile([0.5, 1.0], 12))  # fmt: skip
    path = tmp_path / "s.npz"
    save_study(path, study)
    assert "reader" in pick_lib.DEFAULT_CANDIDATES
    starts = []
    real = pick_lib.fit

    def spy(cfg, st, key, start=None):
        if cfg.model == "reader":
            starts.append(start)
        return real(cfg, st, key, start)

    monkeypatch.setattr(pick_lib, "fit", spy)
    out = tmp_path / "pick"
    assert study_main(["pick", str(path), "--out", str(out), "--candidates", "reader,dragan",
                       "--folds", "2", "--no-progress"]) == 0  # fmt: skip
    rep = json.loads((out / "pick.json").read_text()) if (out / "pick.json").exists() else None
    assert starts and all(s is not None for s in starts)  # every reader fit started from the prior
    cam = scene.camera("observer")
    np.testing.assert_array_equal(np.asarray(starts[0]["camera_pos"][...]), np.asarray(cam.pos))
    assert rep is None or "reader" in json.dumps(rep)


def test_study_camera_is_the_members_own_or_the_datasets():
    cam = people.study_camera(zoo.MEMBERS["anchor"])
    np.testing.assert_array_equal(
        np.asarray(cam.pos), np.asarray(zoo.zoo_camera("zoo_shoulder").pos)
    )
    obs = scene.camera("observer")
    for p in (zoo.MEMBERS["descent"], people.get_people("default")):
        np.testing.assert_array_equal(np.asarray(people.study_camera(p).pos), np.asarray(obs.pos))


def test_the_fits_experiment_refuses_a_users_file_in_the_way(tmp_path, capsys):
    from slotv_jax.experiments.people_loop import learned

    (tmp_path / "answers_learned_tiny.json").write_text('{"mine": 1}')
    with pytest.raises(SystemExit) as e:
        learned.main(["--preset", "tiny", "--population", "anchor", "--sizes", "20,40",
                      "--out", str(tmp_path), "--no-progress"])  # fmt: skip
    assert e.value.code == 2 and "not ours" in capsys.readouterr().err
    assert (tmp_path / "answers_learned_tiny.json").read_text() == '{"mine": 1}'


def test_a_run_never_learns_its_prior_from_the_people_it_is_scored_on(monkeypatch):
    """A draw of the hyper-distribution can be both a prior source and the people a run is
    scored on (``--population random:1003``): it is left out as a zoo member is. And the
    people loop asks for the reader's prior without the population it scores: the name it
    passes reaches ``prior_study``'s ``exclude``."""
    from types import SimpleNamespace

    from slotv_jax.experiments import people_loop as exp
    from slotv_jax.experiments.people_loop import loop

    names = [n for n, _ in prior.sources(exclude=("random:1003",))]
    assert "random:1003" not in names and {"random:1002", "random:1004"} <= set(names)
    assert len(names) == 4 + prior.PRIOR_DRAWS - 1 + len(zoo.MEMBERS)

    asked = []
    monkeypatch.setattr(loop, "_PRETRAINED", {})  # the process's cache is left as it was
    monkeypatch.setattr(prior, "prior_study",
                        lambda *a, exclude=(), **k: asked.append(tuple(exclude)))  # fmt: skip
    monkeypatch.setattr(prior, "prior_params", lambda tc, study, camera: {"theta": 0})
    cfg = exp.tiny()
    xyz, goals, mask = _motions(7, cfg.pool)
    split = SimpleNamespace(xyz=xyz, scene_goals=goals, scene_mask=mask,
                            env_id=np.arange(cfg.pool))  # fmt: skip
    camera = SimpleNamespace(pos=np.zeros(3), rot=np.eye(3))
    for name in ("descent", "random:1003", "default"):
        loop.reader_prior(cfg, split, name, camera)
    assert asked == [("descent",), ("random:1003",), ("default",)]
