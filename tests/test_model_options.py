"""Tests for the MLP observers' options (config.TrainConfig ``activation``, ``start_term``,
``time_weight``; SLOT-V+ and T-REX+ of the planning experiment): an independent float64
NumPy forward pass, the custom first-layer gradients for softplus, invariances, study prefix
scores, packed updates, checkpoints, config errors, and the default being the paper's
network."""

from __future__ import annotations

import dataclasses
import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx
from test_models import REF_TOL, TRANS_TOL, scene_and_path
from test_train import assert_packed_equals_dense, synthetic_split

from slotv_jax import study
from slotv_jax.observers import models, parametric
from slotv_jax.training import checkpoint, types
from slotv_jax.training import config as train_config
from slotv_jax.training import trainer as train

OPTIONS = {  # name -> TrainConfig overrides
    "softplus": dict(activation="softplus"),
    "start": dict(start_term=True),
    "time": dict(time_weight=True),
    "plus": dict(start_term=True, time_weight=True),
    "softplus_plus": dict(activation="softplus", start_term=True, time_weight=True),
}
ALPHA = 1.6  # set instead of the initial 1, so that a wrong exponent would show


def make(method: str, hidden=(32, 16, 8), seed=0, **opts):
    cfg = train_config.quick(method, hidden=hidden, **opts)
    model = models.make_model(cfg, seed)
    if model.raw_alpha is not None:
        model.raw_alpha[...] = jnp.asarray(math.log(math.expm1(ALPHA)), jnp.float32)
    return cfg, model


def numpy_scores(model, xyz, goals, method: str, activation: str) -> np.ndarray:
    """Float64 reference from the parameters: MLP(p_i − g_k) with σ, taken relative to the
    first point's with the start term, the points weighted by (1 − t_i)^α (normalised to
    mean 1), then mean (SLOT-V) or sum (T-REX)."""
    net = model.value if method == "slotv" else model.reward
    ws = [net.first, *net.layers, net.readout]
    sigma = {"relu": lambda h: np.maximum(h, 0.0), "softplus": lambda h: np.logaddexp(0.0, h)}
    h = np.asarray(xyz, np.float64)[:, None, :] - np.asarray(goals, np.float64)[None]
    for i, lin in enumerate(ws):
        h = h @ np.asarray(lin.kernel[...], np.float64)
        if lin.bias is not None:
            h = h + np.asarray(lin.bias[...], np.float64)
        if i < len(ws) - 1:
            h = sigma[activation](h)
    v = h[..., 0]  # (T, G)
    # float32 rounds the values (T of them in T-REX's sum), not their difference
    numpy_scores.value_scale = np.max(np.abs(v)) * (1 if method == "slotv" else v.shape[0])
    if model.start_term:
        v = v - v[:1]
    n = v.shape[0]
    u = np.ones(n)
    if model.raw_alpha is not None:
        a = np.log1p(np.exp(float(model.raw_alpha[...])))
        u = (1.0 - np.arange(n) / (n - 1)) ** a
        u = n * u / u.sum()
    s = (u[:, None] * v).sum(0)
    return s / n if method == "slotv" else s


@pytest.mark.parametrize("option", sorted(OPTIONS))
@pytest.mark.parametrize("method", ["slotv", "trex"])
def test_options_match_float64_reference(method, option):
    opts = OPTIONS[option]
    _, model = make(method, **opts)
    xyz, goals, mask = scene_and_path(5, 4)
    got = np.asarray(model(xyz, goals, mask))
    ref = numpy_scores(model, xyz, goals, method, opts.get("activation", "relu"))
    # the start term subtracts values of similar size: rounding scales with the values
    scale = max(np.max(np.abs(ref[mask])), numpy_scores.value_scale)
    np.testing.assert_allclose(got[mask], ref[mask], rtol=0, atol=REF_TOL * scale)
    assert np.all(np.isneginf(got[~mask]))
    # the terms change the scores (the test would not see them otherwise)
    if "start_term" in opts or "time_weight" in opts:
        plain = numpy_scores(model.__class__((32, 16, 8), rngs=nnx.Rngs(0)), xyz, goals, method,
                             "relu")  # fmt: skip
        assert not np.allclose(ref[mask], plain[mask], rtol=0, atol=1e-3 * scale)


def test_default_is_the_papers_network():
    """Without options the model has exactly the paper's parameters (no α), the points
    count the same, no start term; the options add one parameter, α, starting at 1."""
    for method in ("slotv", "trex"):
        m = models.make_model(train_config.quick(method), 0)
        assert not m.start_term and m.raw_alpha is None and m.point_weights(100) is None
        n = len(jax.tree.leaves(nnx.state(m, nnx.Param)))
        p = models.make_model(train_config.quick(method, start_term=True, time_weight=True), 0)
        assert len(jax.tree.leaves(nnx.state(p, nnx.Param))) == n + 1
        assert float(p.alpha) == pytest.approx(models.ALPHA_INIT, rel=1e-6) == 1.0


def test_time_weights_hand_cases():
    """(1 − t)^α normalised: α = 1 on 3 points is (2/3, 1/3, 0); α = 0 the plain mean; a
    float64 NumPy check at α = 0.7 on 100 points."""
    np.testing.assert_allclose(parametric.time_weights(1.0, 3), [2 / 3, 1 / 3, 0.0], atol=1e-7)
    np.testing.assert_allclose(parametric.time_weights(0.0, 5), np.full(5, 0.2), atol=1e-7)
    u = np.maximum(1.0 - np.arange(100) / 99.0, np.finfo(np.float32).tiny) ** 0.7
    np.testing.assert_allclose(parametric.time_weights(0.7, 100), u / u.sum(), rtol=1e-5)


@pytest.mark.parametrize("backward", [b for b in models.BACKWARDS if b != "autodiff"])
def test_softplus_custom_gradients_equal_autodiff(backward):
    """The fused and recompute first-layer gradients use σ' = sigmoid for softplus: they
    equal autodiff for the parameters and the inputs (float64)."""
    with jax.enable_x64(True):
        m = models.GoalRelativeMLP((24, 16, 8), activation="softplus", rngs=nnx.Rngs(3))
        graphdef, params = nnx.split(m)
        params = jax.tree.map(lambda x: x.astype(jnp.float64), params)
        rng = np.random.default_rng(0)
        xyz = jnp.asarray(rng.uniform(-0.5, 0.5, (3, 7, 3)))
        goals = jnp.asarray(rng.uniform(-0.5, 0.5, (3, 5, 3)))
        wts = jnp.asarray(rng.normal(size=(3, 7, 5)))

        def loss(p, x, gl, bw):
            return jnp.sum(wts * nnx.merge(graphdef, p).grid(x, gl, backward=bw))

        ref = jax.grad(loss, argnums=(0, 1, 2))(params, xyz, goals, "autodiff")
        got = jax.grad(loss, argnums=(0, 1, 2))(params, xyz, goals, backward)
    for a, b in zip(jax.tree.leaves(ref), jax.tree.leaves(got), strict=True):
        assert np.max(np.abs(np.asarray(a))) > 0
        np.testing.assert_allclose(np.asarray(b), np.asarray(a), rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("method", ["slotv", "trex"])
def test_plus_keeps_translation_and_padding_invariance(method):
    _, model = make(method, **OPTIONS["plus"])
    xyz, goals, mask = scene_and_path(6, 4)
    s = np.asarray(model(xyz, goals, mask))
    c = np.array([0.37, -0.21, 0.12], np.float32)
    scale = np.max(np.abs(s[mask]))
    np.testing.assert_allclose(np.asarray(model(xyz + c, goals + c, mask))[mask], s[mask],
                               rtol=0, atol=TRANS_TOL * scale)  # fmt: skip
    dummy = goals.copy()
    dummy[4:] = np.random.default_rng(1).uniform(-1, 1, (4, 3))
    np.testing.assert_array_equal(np.asarray(model(xyz, dummy, mask)), s)


@pytest.mark.parametrize("method", ["slotv", "trex"])
def test_prefix_scores_with_plus(method):
    """Study prefix scores of a SLOT-V+/T-REX+ model: all points seen gives the model's
    scores; L seen points give Σ_{i<L} u_i (f_i − f_0) (/ Σ_{i<L} u_i for SLOT-V)."""
    _, model = make(method, **OPTIONS["plus"])
    xyz, goals, _ = scene_and_path(7, 3)
    full = np.asarray(study.prefix_scores(model, xyz[None], goals[None], jnp.array([100])))[0]
    np.testing.assert_allclose(full, np.asarray(model.scores(xyz, goals)), rtol=0,
                               atol=1e-5 * np.max(np.abs(full)))  # fmt: skip
    L = 37
    got = np.asarray(study.prefix_scores(model, xyz[None], goals[None], jnp.array([L])))[0]
    net = model.value if method == "slotv" else model.reward
    v = np.asarray(net.grid(xyz, goals), np.float64)  # (T, G), checked against NumPy above
    u = np.asarray(model.point_weights(100), np.float64)[:L]
    s = (u[:, None] * (v[:L] - v[:1])).sum(0)
    if method == "slotv":
        s = s / u.sum()
    np.testing.assert_allclose(got, s, rtol=0, atol=1e-5 * np.max(np.abs(s)))


@pytest.mark.slow
def test_packed_updates_exact_and_reach_the_new_parameters():
    """SLOT-V+ updates on the real pairs equal the all-slots update, and the gradient reaches
    α."""
    data = types.trim_goals(types.prepare(synthetic_split(0, 64), "effdist"))
    cfg = train_config.quick("slotv", hidden=(16, 8), batch_size=16, train_size=None,
                       **OPTIONS["plus"])  # fmt: skip
    trainer = train.make_train(cfg, progress=False)
    model = trainer.model(trainer.init(jax.random.key(0)).params)
    batch = [jnp.asarray(x)[:16] for x in data]
    cap = int(np.asarray(batch[2]).sum())
    ga = assert_packed_equals_dense(model, batch, cap, backward="recompute")
    assert abs(float(ga.raw_alpha[...])) > 0


def test_checkpoint_round_trip_and_mismatch(tmp_path):
    """A SLOT-V+ checkpoint loads with its options (same logits); a checkpoint whose config
    lost them does not fit and says so."""
    split = synthetic_split(2, 64)
    cfg = train_config.quick("slotv", hidden=(16, 8), batch_size=16, epochs=1, train_size=None,
                       **OPTIONS["softplus_plus"])  # fmt: skip
    state, _ = train.train_trials(cfg, types.prepare(split, "effdist"), [0], progress=False)
    state = train.select_trial(state, 0)
    path = checkpoint.save(tmp_path / "plus", cfg, state)
    assert json.loads((path / checkpoint.CONFIG_FILE).read_text())["config"]["time_weight"]
    assert checkpoint.load_config(path) == cfg
    obs = checkpoint.load_observer(path)
    model = train.make_train(cfg, progress=False).model(state.params)
    xyz, goals, mask = split.xyz[0], split.goals[0], split.goal_mask[0]
    np.testing.assert_array_equal(np.asarray(obs(xyz, goals, mask)),
                                  np.asarray(model(xyz, goals, mask)))  # fmt: skip
    with pytest.raises(ValueError, match=r"start_term \(saved True, requested False\)"):
        checkpoint.restore(path, dataclasses.replace(cfg, start_term=False))
    # a config edited to claim time weights its parameters lack: they do not fit
    bare = dataclasses.replace(cfg, time_weight=False, start_term=False)
    state, _ = train.train_trials(bare, types.prepare(split, "effdist"), [0], progress=False)
    plain = checkpoint.save(tmp_path / "plain", bare, train.select_trial(state, 0))
    edited = json.loads((plain / checkpoint.CONFIG_FILE).read_text())
    edited["config"]["time_weight"] = True
    (plain / checkpoint.CONFIG_FILE).write_text(json.dumps(edited))
    with pytest.raises(ValueError, match="does not fit"):
        checkpoint.load_observer(plain)


def test_config_options_errors_and_overrides():
    with pytest.raises(ValueError, match="activation"):
        train_config.quick("slotv", activation="gelu")
    with pytest.raises(ValueError, match="start_term"):
        train_config.quick("slotv", start_term="yes")
    with pytest.raises(ValueError, match="time_weight"):
        train_config.quick("slotv", time_weight=1)
    with pytest.raises(ValueError, match="archetype"):
        train_config.archetype("quick", "dragan", start_term=True)
    c = train_config.apply_overrides(
        train_config.quick("slotv"), ["start_term=true", "time-weight=1", "activation=softplus"]
    )
    assert (c.start_term, c.time_weight, c.activation) == (True, True, "softplus")
    assert train_config.TrainConfig.from_dict(c.to_dict()) == c
    with pytest.raises(ValueError, match="start_term='maybe'"):
        train_config.apply_overrides(c, ["start_term=maybe"])
