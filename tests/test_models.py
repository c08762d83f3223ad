"""Tests for slotv_jax.observers.models: an independent NumPy float64 forward pass, padding
invariance, translation invariance, the first-layer rewrite, mixed precision,
T-REX pair sampling and input validation."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx

import slotv_jax  # noqa: F401  (applies the XLA CPU setting before JAX starts)
from slotv_jax.observers import models
from slotv_jax.training import config as train_config

REF_TOL = 2e-5  # float32 model against the float64 NumPy reference (relative to max |s|)
INV_TOL = 1e-6  # probabilities under padding changes / slot moves
TRANS_TOL = 2e-5  # scores under a common translation (relative to max |s|)
BF16_TOL = 3e-2  # bfloat16 hidden layers against float32 (relative to max |s|)
T = 100
HIDDEN = (32, 16, 8)  # with an extra hidden layer


def scene_and_path(seed: int, n_goals: int = 3):
    """Goals on the table, a path from above the table to goal 0 (float32)."""
    rng = np.random.default_rng(seed)
    goals = np.zeros((8, 3), np.float32)
    goals[:n_goals, 0] = rng.uniform(0.3, 0.7, n_goals)
    goals[:n_goals, 1] = np.linspace(-0.4, 0.4, n_goals) + rng.uniform(-0.02, 0.02, n_goals)
    goals[:n_goals, 2] = 0.025
    mask = np.arange(8) < n_goals
    start = np.array([0.31, 0.0, 0.49])
    t = np.linspace(0, 1, T)[:, None]
    bend = np.sin(np.pi * t) * rng.uniform(-0.1, 0.1, 3)
    xyz = ((1 - t) * start + t * goals[0] + bend).astype(np.float32)
    return xyz, goals, mask


def make(method: str, hidden=HIDDEN, compute_dtype="float32", seed=0):
    cfg = train_config.quick(method, hidden=hidden, compute_dtype=compute_dtype)
    return models.make_model(cfg, seed)


def numpy_scores(model, xyz, goals, method: str) -> np.ndarray:
    """Independent float64 forward pass from the parameters: MLP(p_i − g_k), then mean/sum."""
    net = model.value if method == "slotv" else model.reward
    ws = [net.first, *net.layers, net.readout]
    x = np.asarray(xyz, np.float64)[:, None, :] - np.asarray(goals, np.float64)[None]
    h = x
    for i, lin in enumerate(ws):
        h = h @ np.asarray(lin.kernel[...], np.float64)
        if lin.bias is not None:
            h = h + np.asarray(lin.bias[...], np.float64)
        if i < len(ws) - 1:
            h = np.maximum(h, 0.0)
    v = h[..., 0]  # (T, G)
    return v.mean(0) if method == "slotv" else v.sum(0)


def probs(logits):
    return np.asarray(jax.nn.softmax(logits))


@pytest.mark.parametrize("method", ["slotv", "trex"])
def test_scores_match_float64_reference(method):
    model = make(method)
    xyz, goals, mask = scene_and_path(1, 4)
    got = np.asarray(model(xyz, goals, mask))
    ref = numpy_scores(model, xyz, goals, method)
    scale = np.max(np.abs(ref[mask]))
    np.testing.assert_allclose(got[mask], ref[mask], rtol=0, atol=REF_TOL * scale)
    assert np.all(np.isneginf(got[~mask]))


@pytest.mark.parametrize("method", ["slotv", "trex"])
def test_padding_invariance(method):
    model = make(method)
    xyz, goals, mask = scene_and_path(2, 3)
    p = probs(model(xyz, goals, mask))
    assert np.all(p[~mask] == 0.0)
    np.testing.assert_allclose(p[mask].sum(), 1.0, atol=1e-6)

    # dummy padded goals anywhere (even on top of the path) change nothing
    dummy = goals.copy()
    dummy[3:] = np.random.default_rng(0).uniform(-1, 1, (5, 3))
    dummy[5] = xyz[50]
    np.testing.assert_allclose(probs(model(xyz, dummy, mask)), p, rtol=0, atol=INV_TOL)

    # moving real goals to other slots, together with their mask, permutes the probabilities
    perm = np.array([6, 0, 7, 1, 2, 3, 4, 5])  # new slot j holds old slot perm[j]
    p2 = probs(model(xyz, goals[perm], mask[perm]))
    np.testing.assert_allclose(p2, p[perm], rtol=0, atol=INV_TOL)

    # fewer real goals: the remaining ones keep their relative probabilities
    mask2 = mask.copy()
    mask2[2] = False
    p3 = probs(model(xyz, goals, mask2))
    np.testing.assert_allclose(p3[:2], p[:2] / p[:2].sum(), rtol=0, atol=INV_TOL)


@pytest.mark.parametrize("method", ["slotv", "trex"])
def test_translating_scene_and_path_leaves_scores_unchanged(method):
    model = make(method)
    xyz, goals, mask = scene_and_path(3, 5)
    s = np.asarray(model(xyz, goals, mask))
    c = np.array([0.37, -0.21, 0.12], np.float32)
    s2 = np.asarray(model(xyz + c, goals + c, mask))
    scale = np.max(np.abs(s[mask]))
    np.testing.assert_allclose(s2[mask], s[mask], rtol=0, atol=TRANS_TOL * scale)
    # and V itself, pointwise
    net = model.value if method == "slotv" else model.reward
    v = np.asarray(net(xyz, goals[1]))
    v2 = np.asarray(net(xyz + c, goals[1] + c))
    np.testing.assert_allclose(v2, v, rtol=0, atol=TRANS_TOL * np.max(np.abs(v)))


def test_grid_equals_pointwise_value():
    """The W1 r − (W1 g − b1) rewrite equals the plain layer on r − g."""
    model = make("slotv")
    xyz, goals, _ = scene_and_path(4, 6)
    grid = np.asarray(model.value.grid(xyz, goals))  # (T, 8)
    direct = np.asarray(model.value(xyz[:, None, :], goals[None, :, :]))
    np.testing.assert_allclose(grid, direct, rtol=0, atol=REF_TOL * np.max(np.abs(direct)))
    # batched leading axes work the same
    b = np.asarray(model.scores(np.stack([xyz, xyz[::-1]]), np.stack([goals, goals])))
    np.testing.assert_allclose(b[0], grid.mean(0), rtol=0, atol=1e-6 * np.max(np.abs(grid)))


def test_bfloat16_compute_keeps_float32_params():
    m32 = make("slotv", hidden=(64, 32))
    m16 = make("slotv", hidden=(64, 32), compute_dtype="bfloat16")
    _, p32 = nnx.split(m32)
    _, p16 = nnx.split(m16)
    assert all(x.dtype == jnp.float32 for x in jax.tree.leaves(p16))
    for a, b in zip(jax.tree.leaves(p32), jax.tree.leaves(p16), strict=True):
        np.testing.assert_array_equal(a, b)  # same init from the same seed
    xyz, goals, mask = scene_and_path(5, 4)
    s32 = np.asarray(m32(xyz, goals, mask))
    s16 = m16(xyz, goals, mask)
    assert s16.dtype == jnp.float32
    s16 = np.asarray(s16)
    scale = np.max(np.abs(s32[mask]))
    assert np.max(np.abs(s16[mask] - s32[mask])) < BF16_TOL * scale
    assert not np.allclose(s16[mask], s32[mask], rtol=0, atol=1e-7 * scale)  # really bf16


def test_model_compiles_once():
    model = make("trex")
    graphdef, params = nnx.split(model)
    traces = []

    @jax.jit
    def f(params, xyz, goals, mask):
        traces.append(1)
        return nnx.merge(graphdef, params)(xyz, goals, mask)

    for seed in range(3):
        xyz, goals, mask = scene_and_path(seed, 2 + seed)
        f(params, xyz, goals, mask)
    assert len(traces) == 1


def test_trex_pairs_follow_spec():
    """Pairs: uniform trajectories, uniform real goal slots, label 1[y2 > y1]
    (:ref:`concepts-trex`)."""
    rng = np.random.default_rng(0)
    n = 40
    counts = rng.choice([2, 3, 5, 6], n)
    mask = np.arange(8)[None] < counts[:, None]
    labels = np.where(mask, rng.uniform(0.01, 1, (n, 8)), 0.0)
    labels /= labels.sum(-1, keepdims=True)
    labels[0, :2] = 0.5  # exact tie between two goals of trajectory 0
    n_pairs = 40_000
    idx, slot, lab = models.sample_trex_pairs(
        jax.random.key(1), jnp.asarray(mask), jnp.asarray(labels, jnp.float32), n_pairs
    )
    idx, slot, lab = np.asarray(idx), np.asarray(slot), np.asarray(lab)
    assert idx.shape == (n_pairs, 2) and slot.shape == (n_pairs, 2) and lab.shape == (n_pairs,)
    assert np.all(slot < counts[idx]) and np.all(slot >= 0)  # only real goals
    y = labels.astype(np.float32)[idx, slot]
    np.testing.assert_array_equal(lab, (y[:, 1] > y[:, 0]).astype(np.float32))
    # uniform over trajectories: every count within 6 SD of its mean
    hits = np.bincount(idx.ravel(), minlength=n)
    mean = 2 * n_pairs / n
    assert np.all(np.abs(hits - mean) < 6 * np.sqrt(mean))
    # uniform over the real goals of a 6-goal trajectory
    six = idx == np.flatnonzero(counts == 6)[0]
    per_slot = np.bincount(slot[six], minlength=8)
    assert per_slot[6:].sum() == 0
    m = six.sum() / 6
    assert np.all(np.abs(per_slot[:6] - m) < 6 * np.sqrt(m))
    # ties are labelled 0
    same = (idx[:, 0] == 0) & (idx[:, 1] == 0) & (slot[:, 0] != slot[:, 1]) & (slot.max(1) < 2)
    assert same.any() and np.all(lab[same] == 0)


def test_observer_input_validation():
    xyz, goals, mask = scene_and_path(6)
    models.check_observer_inputs(xyz, goals, mask)
    with pytest.raises(ValueError, match="xyz"):
        models.check_observer_inputs(xyz[:, :2], goals, mask)
    with pytest.raises(ValueError, match="xyz"):
        models.check_observer_inputs(xyz[:1], goals, mask)
    bad = xyz.copy()
    bad[3, 1] = np.nan
    with pytest.raises(ValueError, match="xyz: expected finite"):
        models.check_observer_inputs(bad, goals, mask)
    with pytest.raises(ValueError, match="goals"):
        models.check_observer_inputs(xyz, goals[:5], mask)
    with pytest.raises(ValueError, match=r"goal_mask.*none"):
        models.check_observer_inputs(xyz, goals, np.zeros(8, bool))
    with pytest.raises(ValueError, match="compute_dtype"):
        models.GoalRelativeMLP((4,), compute_dtype="float16", rngs=nnx.Rngs(0))


@pytest.mark.parametrize("backward", [b for b in models.BACKWARDS if b != "autodiff"])
@pytest.mark.parametrize("shape", [(3, 7, 5), (2, 2, 6, 1)])  # SLOT-V (B, T, G); T-REX pairs
def test_custom_first_layer_gradients_equal_autodiff(backward, shape):
    """Every training gradient implementation gives autodiff's gradient, for the parameters
    and for the inputs, on random data with a weighted loss over all (point, goal) values."""
    *batch, t, g = shape
    with jax.enable_x64(True):
        m = models.GoalRelativeMLP((24, 16, 8), rngs=nnx.Rngs(3))
        graphdef, params = nnx.split(m)
        params = jax.tree.map(lambda x: x.astype(jnp.float64), params)
        rng = np.random.default_rng(0)
        xyz = jnp.asarray(rng.uniform(-0.5, 0.5, (*batch, t, 3)))
        goals = jnp.asarray(rng.uniform(-0.5, 0.5, (*batch, g, 3)))
        wts = jnp.asarray(rng.normal(size=(*batch, t, g)))

        def loss(p, x, gl, bw):
            return jnp.sum(wts * nnx.merge(graphdef, p).grid(x, gl, backward=bw))

        ref = jax.grad(loss, argnums=(0, 1, 2))(params, xyz, goals, "autodiff")
        got = jax.grad(loss, argnums=(0, 1, 2))(params, xyz, goals, backward)
    for a, b in zip(jax.tree.leaves(ref), jax.tree.leaves(got), strict=True):
        assert np.max(np.abs(np.asarray(a))) > 0  # the loss reaches every parameter
        np.testing.assert_allclose(np.asarray(b), np.asarray(a), rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("reduce", ["mean", "sum"])
@pytest.mark.parametrize("backward", models.BACKWARDS)
def test_integrate_equals_reduced_grid(reduce, backward):
    """Reducing the last hidden activation before the linear readout gives the reduced
    per-point values, and the same gradients, for the parameters and the inputs (float64);
    an unknown reduction is refused by name."""
    with jax.enable_x64(True):
        m = models.GoalRelativeMLP((24, 16, 8), rngs=nnx.Rngs(5))
        graphdef, params = nnx.split(m)
        params = jax.tree.map(lambda x: x.astype(jnp.float64), params)
        rng = np.random.default_rng(3)
        xyz = jnp.asarray(rng.uniform(-0.5, 0.5, (3, 11, 3)))
        goals = jnp.asarray(rng.uniform(-0.5, 0.5, (3, 5, 3)))
        wts = jnp.asarray(rng.normal(size=(3, 5)))
        red = {"mean": jnp.mean, "sum": jnp.sum}[reduce]

        def ref(p, x, gl):
            return jnp.sum(wts * red(nnx.merge(graphdef, p).grid(x, gl), axis=-2))

        def got(p, x, gl):
            mlp = nnx.merge(graphdef, p)
            return jnp.sum(wts * mlp.integrate(x, gl, reduce=reduce, backward=backward))

        v_ref, g_ref = jax.value_and_grad(ref, argnums=(0, 1, 2))(params, xyz, goals)
        v_got, g_got = jax.value_and_grad(got, argnums=(0, 1, 2))(params, xyz, goals)
    np.testing.assert_allclose(float(v_got), float(v_ref), rtol=1e-12)
    for a, b in zip(jax.tree.leaves(g_ref), jax.tree.leaves(g_got), strict=True):
        assert np.max(np.abs(np.asarray(a))) > 0
        np.testing.assert_allclose(np.asarray(b), np.asarray(a), rtol=1e-10, atol=1e-12)
    with pytest.raises(ValueError, match="reduce"):
        m.integrate(xyz.astype(jnp.float32), goals.astype(jnp.float32), reduce="max")


def test_integrate_bfloat16_close_to_float32():
    """In bfloat16 compute, the pooled readout stays within bfloat16 rounding of the
    float32 model's reduced per-point values."""
    rng = np.random.default_rng(4)
    xyz = jnp.asarray(rng.uniform(-0.5, 0.5, (4, 50, 3)), jnp.float32)
    goals = jnp.asarray(rng.uniform(-0.5, 0.5, (4, 6, 3)), jnp.float32)
    m32 = models.GoalRelativeMLP((64, 32), rngs=nnx.Rngs(6))
    m16 = models.GoalRelativeMLP((64, 32), compute_dtype="bfloat16", rngs=nnx.Rngs(6))
    ref = np.asarray(m32.grid(xyz, goals).mean(axis=-2))
    got = np.asarray(m16.integrate(xyz, goals))
    assert got.dtype == np.float32
    np.testing.assert_allclose(got, ref, rtol=0, atol=0.02 * np.abs(ref).max())
