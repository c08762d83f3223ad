"""Scenes: sampler invariants, determinism, and validation."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from slotv_jax.world import scene as S

CFG = S.SceneConfig()


@pytest.fixture(scope="module")
def scenes():
    keys = jax.random.split(jax.random.key(7), 2000)
    draw = jax.jit(jax.vmap(lambda k: S.sample_scene(k, S.sample_goal_count(k, (1, 2, 4, 7, 8)))))
    return jax.tree.map(np.asarray, draw(keys))


def test_regions_spacing_and_padding(scenes):
    g, m = scenes.goals, scenes.goal_mask
    real = g[m]
    assert np.all((real[:, 0] >= 0.30) & (real[:, 0] <= 0.70))
    assert np.all((real[:, 1] >= -0.45) & (real[:, 1] <= 0.45))
    np.testing.assert_array_equal(real[:, 2], np.float32(0.025))
    assert np.all(g[~m] == 0.0)
    d = np.linalg.norm(g[:, :, None, :2] - g[:, None, :, :2], axis=-1)
    pair = m[:, :, None] & m[:, None, :] & ~np.eye(8, dtype=bool)
    assert d[pair].min() >= CFG.min_spacing - 1e-6
    # Real goals first, and n_goals agrees with the mask.
    np.testing.assert_array_equal(m.sum(-1), scenes.n_goals)
    np.testing.assert_array_equal(m, np.arange(8) < scenes.n_goals[:, None])
    S.check_scene(scenes, batched=True)


def test_goal_counts_are_uniform_over_the_set(scenes):
    counts = np.bincount(scenes.n_goals, minlength=9)
    assert set(np.flatnonzero(counts)) == {1, 2, 4, 7, 8}
    assert counts[[1, 2, 4, 7, 8]].min() > 2000 / 5 * 0.8


def test_deterministic_in_key():
    a = S.sample_scene(jax.random.key(3), 6)
    b = S.sample_scene(jax.random.key(3), 6)
    c = S.sample_scene(jax.random.key(4), 6)
    np.testing.assert_array_equal(a.goals, b.goals)
    assert not np.array_equal(a.goals, c.goals)


def test_check_scene_rejects_violations():
    s = jax.tree.map(np.asarray, S.sample_scene(jax.random.key(0), 3))
    close = s.goals.copy()
    close[1] = close[0] + [0.05, 0.0, 0.0]
    with pytest.raises(ValueError, match="spacing"):
        S.check_scene(dataclasses.replace(s, goals=close))
    dup = s.goals.copy()
    dup[1] = dup[0]
    with pytest.raises(ValueError, match="same position"):
        S.check_scene(dataclasses.replace(s, goals=dup))
    gap = s.goal_mask.copy()
    gap[1], gap[4] = False, True
    with pytest.raises(ValueError, match="first slots"):
        S.check_scene(dataclasses.replace(s, goal_mask=gap))
    nan = s.goals.copy()
    nan[0, 0] = np.nan
    with pytest.raises(ValueError, match="goals: expected finite"):
        S.check_scene(dataclasses.replace(s, goals=nan))
    with pytest.raises(ValueError, match="goal_mask"):
        S.check_scene(dataclasses.replace(s, goal_mask=np.zeros(8, bool), n_goals=np.int32(0)))
    with pytest.raises(ValueError, match=r"goals: expected shape \(8, 3\)"):
        S.check_scene(dataclasses.replace(s, goals=s.goals[:5]))


@pytest.mark.parametrize(
    "kw",
    [{"min_spacing": 0.0}, {"min_spacing": -1.0}, {"x_range": (0.7, 0.3)}, {"cube_z": np.nan}],
)
def test_scene_config_validation(kw):
    with pytest.raises(ValueError, match="SceneConfig"):
        S.SceneConfig(**kw)


def test_sampler_compiles_once():
    traces = []

    @jax.jit
    def draw(key, n):
        traces.append(1)
        return S.sample_scene(key, n)

    for i in range(4):
        draw(jax.random.key(i), jnp.int32(2 + i))
    assert len(traces) == 1
