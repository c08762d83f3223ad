"""Tests for slotv_jax.training.config, slotv_jax.train and slotv_jax.training.evaluate: presets,
learning on a tiny dataset, vmap and multi-device equivalence, in-loop validation, progress reports,
accuracy against a NumPy reference, and input validation."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from compile_log import backend_compiles
from flax import nnx

import slotv_jax  # applies the XLA CPU setting before JAX starts
from slotv_jax.train import cli as train_cli
from slotv_jax.training import checkpoint, evaluate, losses, types
from slotv_jax.training import config as train_config
from slotv_jax.training import trainer as train

PROB_TOL = 1e-5  # goal probabilities of two runs that differ only in summation order
STEP_FRAC = 1e-2  # their parameters differ by less than this fraction of one update (lr)
T = 100
HOME = np.array([0.3069, 0.0, 0.4869])


# ------------------------------------------------------------- a tiny synthetic dataset


@dataclasses.dataclass(frozen=True)
class TinySplit:
    """The fields of slotv_jax.data.Split that training reads."""

    name: str
    xyz: np.ndarray  # (N, T, 3)
    env_id: np.ndarray  # (N,)
    scene_goals: np.ndarray  # (S, 8, 3)
    scene_mask: np.ndarray  # (S, 8)
    labels: dict  # name -> (N, 8)

    @property
    def goals(self):
        return self.scene_goals[self.env_id]

    @property
    def goal_mask(self):
        return self.scene_mask[self.env_id]

    def __len__(self):
        return len(self.xyz)


def effdist_np(xyz, goals, mask, beta=5.0):
    """:ref:`concepts-effdist` in float64: softmax over real goals of −β · mean_i ‖p_i − g_k‖."""
    d = np.linalg.norm(xyz[:, :, None, :] - goals[:, None, :, :], axis=-1).mean(1)
    s = np.where(mask, -beta * d, -np.inf)
    e = np.exp(s - s.max(-1, keepdims=True))
    return e / e.sum(-1, keepdims=True)


def synthetic_split(seed: int, n: int, n_scenes: int = 20, counts=(2, 3, 5, 6), name="train"):
    """:ref:`concepts-scenes`, :ref:`concepts-trajectories` without the IK: cubes on the table,
    piecewise-linear via-point paths from the home TCP to the target, resampled to 100 points by arc
    length; EffDist labels."""
    rng = np.random.default_rng(seed)
    sg = np.zeros((n_scenes, 8, 3), np.float32)
    sm = np.zeros((n_scenes, 8), bool)
    for s in range(n_scenes):
        c = int(rng.choice(counts))
        pts: list[np.ndarray] = []
        while len(pts) < c:
            p = np.array([rng.uniform(0.3, 0.7), rng.uniform(-0.45, 0.45), 0.025])
            if all(np.linalg.norm(p - q) >= 0.1 for q in pts):
                pts.append(p)
        sg[s, :c], sm[s, :c] = pts, True
    env = rng.integers(0, n_scenes, n).astype(np.int32)
    xyz = np.zeros((n, T, 3), np.float32)
    for i in range(n):
        k = rng.integers(0, sm[env[i]].sum())
        via = rng.uniform([0.25, -0.5, 0.1], [0.7, 0.5, 0.4], (rng.integers(3, 6), 3))
        path = np.vstack([HOME, via, sg[env[i], k]])
        arc = np.concatenate([[0], np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))])
        u = np.linspace(0, arc[-1], T)
        xyz[i] = np.stack([np.interp(u, arc, path[:, j]) for j in range(3)], 1)
    y = effdist_np(xyz.astype(np.float64), sg[env].astype(np.float64), sm[env])
    return TinySplit(name, xyz, env, sg, sm, {"effdist": y.astype(np.float32)})


@pytest.fixture(scope="module")
def tiny():
    return synthetic_split(0, 400), synthetic_split(1, 200, name="trajectory_test")


def small_cfg(method, **kw):
    base = dict(hidden=(16, 8), batch_size=16, epochs=2, train_size=None, learning_rate=0.002)
    return train_config.quick(method, **{**base, **kw})


def probabilities(cfg, params, data, n=64):
    model = train.make_train(cfg, progress=False).model(params)
    return np.asarray(jax.nn.softmax(model(data.xyz[:n], data.goals[:n], data.goal_mask[:n])))


def assert_same_run(cfg, params_a, params_b, probs_a, probs_b):
    """Two runs that differ only in float summation order: the same function to float
    tolerance, and parameters within a small fraction of one optimiser step.

    RMSprop and Adam divide each gradient by its running RMS. In a direction the loss cannot
    see (e.g. the bias of a last-hidden-layer unit that is active on every row shifts all goal
    scores equally) the gradient is rounding noise (~1e-10), which that division turns into
    steps of ~1e-2·lr. A tolerance relative to the parameter's own size would call that a
    different run; one relative to the step size does not, while a real divergence (another
    batch, pair or key) moves parameters by whole steps (~lr).
    """
    np.testing.assert_allclose(probs_a, probs_b, rtol=0, atol=PROB_TOL)
    for x, y in zip(jax.tree.leaves(params_a), jax.tree.leaves(params_b), strict=True):
        np.testing.assert_allclose(
            np.asarray(x), np.asarray(y), rtol=0, atol=STEP_FRAC * cfg.learning_rate
        )


# ------------------------------------------------------------- config


def test_paper_presets_follow_spec():
    s = train_config.paper("slotv")
    assert (s.hidden, s.optimizer, s.learning_rate, s.rho, s.momentum) == (
        (1536, 768), "rmsprop", 0.005, 0.9, 0.0)  # fmt: skip
    assert (s.batch_size, s.epochs, s.train_size, s.compute_dtype) == (32, 15, None, "float32")
    t = train_config.paper("trex")
    assert (t.hidden, t.optimizer, t.learning_rate, t.b1, t.b2) == (
        (1792, 768), "adam", 0.005, 0.9, 0.999)  # fmt: skip
    assert (t.batch_size, t.epochs) == (128, 25)
    q = train_config.quick("trex", epochs=1)
    assert q.epochs == 1 and q.method == "trex"


def test_config_overrides_roundtrip_and_errors():
    cfg = train_config.apply_overrides(
        train_config.paper("slotv"),
        ["hidden=256,128,64", "epochs=3", "learning_rate=0.01", "train_size=none", "eval-every=10"],
    )
    assert cfg.hidden == (256, 128, 64) and cfg.epochs == 3 and cfg.learning_rate == 0.01
    assert cfg.train_size is None and cfg.eval_every == 10
    assert train_config.TrainConfig.from_dict(json.loads(cfg.to_json())) == cfg
    assert cfg.steps_per_epoch(1000) == 1000 // 32 and cfg.block_size(1000) == 10
    assert cfg.evals_per_epoch(1000) == 3
    with pytest.raises(ValueError, match="unknown field"):
        train_config.apply_overrides(cfg, ["hiden=3"])
    with pytest.raises(ValueError, match="method"):
        train_config.TrainConfig(method="dqn")
    with pytest.raises(ValueError, match="learning_rate"):
        train_config.paper("slotv", learning_rate=-1.0)
    with pytest.raises(ValueError, match="hidden"):
        train_config.paper("slotv", hidden=())
    with pytest.raises(ValueError, match="preset"):
        train_config.preset("huge", "slotv")


# ------------------------------------------------------------- learning


def excess_loss(loss, labels):
    """Cross-entropy minus the labels' entropy: the KL divergence the model can remove."""
    y = np.asarray(labels, np.float64)
    h = -np.sum(np.where(y > 0, y * np.log(np.where(y > 0, y, 1)), 0), -1).mean()
    return np.asarray(loss) - h


def test_slotv_learns_effdist(tiny_data):
    """Acceptance: ≥ 0.95 test accuracy on EffDist labels (which V can represent exactly),
    trained on the 300 trajectories of the generated tiny dataset."""
    cfg = small_cfg("slotv", hidden=(64, 32), epochs=20)
    data = types.prepare(tiny_data["train"], "effdist")
    state, metrics = train.train_trials(cfg, data, [0], progress=False)
    kl = excess_loss(metrics.loss[0], data.labels)
    assert kl[-1, -1] < 0.5 * kl[0, 0], kl  # the removable part of the loss at least halves
    for split in ("trajectory_test", "position_test"):
        acc = evaluate.accuracy(cfg, state.params, tiny_data[split], "effdist")
        assert acc.shape == (1,) and acc[0] >= 0.95, (split, acc)


def test_trex_learns_well_above_chance(tiny_data):
    cfg = small_cfg("trex", hidden=(32, 32), epochs=12, batch_size=32)
    data = types.prepare(tiny_data["train"], "effdist")
    state, metrics = train.train_trials(cfg, data, [0], progress=False)
    loss = np.asarray(metrics.loss[0])
    assert loss[-3:].mean() < 0.7 * loss[0, :1].mean(), loss  # BCE falls
    te = tiny_data["trajectory_test"]
    chance = np.mean(1.0 / te.goal_mask.sum(-1))
    acc = evaluate.accuracy(cfg, state.params, te, "effdist")[0]
    assert acc > chance + 0.3, (acc, chance)
    pair = evaluate.pairwise_accuracy(cfg, state.params, te, "effdist", n_pairs=2000)[0]
    assert pair > 0.7, pair  # ordering pairs: chance is 0.5


def test_cli_trains_checkpoints_and_resumes(tiny_data, tiny_cfg, tmp_path, capsys):
    from slotv_jax import data as data_lib

    (tmp_path / "data").mkdir()
    for name in train_cli.TEST_SPLITS:
        data_lib.save_split(tmp_path / "data", tiny_data[name], tiny_cfg)
    ck = tmp_path / "ck"
    args = ["--data", str(tmp_path / "data"), "--labeler", "effdist", "--method", "trex",
            "--out", str(ck), "--set", "hidden=8,8", "--set", "train_size=none",
            "--no-progress"]  # fmt: skip
    assert train_cli.main([*args, "--epochs", "1"]) == 0
    doc = json.loads((ck / "config.json").read_text())
    assert doc["epoch"] == 1 and doc["config"]["hidden"] == [8, 8]
    assert set(doc["meta"]["accuracy"]) == set(train_cli.TEST_SPLITS)
    out = capsys.readouterr().out
    assert "accuracy goal_count_test" in out and "epoch 1/1" in out
    assert train_cli.main([*args, "--epochs", "2", "--resume"]) == 0
    out = capsys.readouterr().out
    assert "resuming from" in out and "epoch 2/2" in out and "epoch 1/2" not in out
    assert json.loads((ck / "config.json").read_text())["epoch"] == 2
    with pytest.raises(SystemExit):  # neither --resume nor --overwrite: refused, untouched
        train_cli.main([*args, "--epochs", "3"])
    assert "pass --resume to continue" in capsys.readouterr().err
    assert json.loads((ck / "config.json").read_text())["epoch"] == 2
    obs = slotv_jax.load_observer(ck)
    s = tiny_data["trajectory_test"]
    assert obs(s.xyz[0], s.goals[0], s.goal_mask[0]).shape == (8,)


# ------------------------------------------------------------- equivalences


@pytest.mark.parametrize("method", ["slotv", "trex"])
def test_vmapped_trials_equal_one_by_one(tiny, method):
    tr, _ = tiny
    cfg = small_cfg(method, epochs=1, train_size=128)
    data = types.prepare(tr, "effdist")
    states, metrics = train.train_trials(cfg, data, [3, 7], progress=False)
    trainer = train.make_train(cfg, progress=False)
    f = jax.jit(trainer.train)
    for i, seed in enumerate([3, 7]):
        s, m = f(jax.random.key(seed), data)
        p_i = train.select_trial(states.params, i)
        pa, pb = probabilities(cfg, p_i, data), probabilities(cfg, s.params, data)
        assert_same_run(cfg, p_i, s.params, pa, pb)
        np.testing.assert_allclose(metrics.loss[i], m.loss, rtol=PROB_TOL)
    a, b = (np.asarray(jax.tree.leaves(states.params)[0][i]) for i in (0, 1))
    assert not np.allclose(a, b)  # different seeds really differ
    # without eval_every nothing is validated
    assert metrics.eval_accuracy.shape == (2, 1, 0) and np.all(np.isnan(metrics.start_accuracy))


def test_trim_goals_cuts_only_unused_slots():
    xyz = np.zeros((2, T, 3), np.float32)
    goals = np.arange(48, dtype=np.float32).reshape(2, 8, 3)
    mask = np.zeros((2, 8), bool)
    mask[0, [0, 1]] = True
    mask[1, [0, 4]] = True  # a gap: slot 4 is real, so slots 0..4 stay
    labels = np.where(mask, 0.5, 0.0).astype(np.float32)
    d = types.TrainData(xyz, goals, mask, labels)
    t = types.trim_goals(d)
    assert t.goals.shape == (2, 5, 3) and t.goal_mask.shape == (2, 5) and t.labels.shape == (2, 5)
    np.testing.assert_array_equal(t.goals, goals[:, :5])
    np.testing.assert_array_equal(t.goal_mask, mask[:, :5])
    assert t.xyz is xyz
    full = d._replace(goal_mask=np.ones((2, 8), bool))
    assert types.trim_goals(full) is full


@pytest.mark.parametrize("method", ["slotv", "trex"])
def test_training_on_trimmed_goal_slots_is_the_same_run(tiny, method):
    """train_trials cuts the unused padded slots (6 of 8 remain here); the loop on all 8
    slots is the same run, and so is the accuracy."""
    tr, te = tiny
    cfg = small_cfg(method, epochs=1, train_size=128)
    data = types.prepare(tr, "effdist")
    assert types.trim_goals(data).goals.shape[1] == 6
    states, _ = train.train_trials(cfg, data, [5], progress=False)
    trainer = train.make_train(cfg, progress=False)
    full, _ = jax.jit(trainer.train)(jax.random.key(5), data)  # 8 slots
    p_trim = train.select_trial(states.params, 0)
    pa, pb = probabilities(cfg, p_trim, data), probabilities(cfg, full.params, data)
    assert_same_run(cfg, p_trim, full.params, pa, pb)
    test = types.prepare(te, "effdist")
    ev = trainer.replicate(trainer.eval_data(test, size=len(te)))  # 8 slots, untrimmed
    np.testing.assert_allclose(
        evaluate.accuracy(cfg, full.params, test), float(jax.jit(trainer.accuracy)(full.params, ev))
    )


def assert_packed_equals_dense(model, batch, cap: int, backward: str = "autodiff"):
    """Loss and gradient of the packed SLOT-V update (``backward`` for the packed one)
    equal the all-slots update's; returns the all-slots gradient."""

    def dense(m):
        return losses.slotv_loss(m, *batch, backward="autodiff")

    def pack(m):
        return losses.slotv_loss_packed(m, *batch, capacity=cap, backward=backward)

    (la, ga), (lb, gb) = (nnx.value_and_grad(f)(model) for f in (dense, pack))
    np.testing.assert_allclose(float(lb), float(la), rtol=1e-6)
    for a, b in zip(jax.tree.leaves(ga), jax.tree.leaves(gb), strict=True):
        np.testing.assert_allclose(np.asarray(b), np.asarray(a), rtol=1e-4, atol=1e-6)
    return ga


@pytest.mark.slow
def test_packed_slotv_updates_are_exact(tiny):
    """SLOT-V updates on the batch's real (trajectory, goal) pairs: the capacity covers every
    batch of the run (counted independently here), and loss and gradient equal the
    all-slots update."""
    tr, _ = tiny
    cfg = small_cfg("slotv", epochs=3, train_size=None)
    data = types.trim_goals(types.prepare(tr, "effdist"))
    trainer = train.make_train(cfg, progress=False)
    keys = jax.vmap(train.Trainer.state_key)(train.trial_keys([0, 1]))
    cap = trainer.pair_capacity(keys, data.goal_mask, range(cfg.epochs))
    counts = np.asarray(data.goal_mask).sum(-1)
    most = max(
        counts[np.asarray(trainer.slotv_batches(k, e, len(counts)))].sum(-1).max()
        for k in keys
        for e in range(cfg.epochs)
    )
    assert most <= cap < most + 8 and cap % 8 == 0
    assert 0 < cap < cfg.batch_size * data.goals.shape[1]  # fewer than all slots: packing is on
    packed = train.packed_trainer(trainer, keys, data, range(cfg.epochs))
    assert packed.packed_pairs == cap

    idx = np.asarray(trainer.slotv_batches(keys[0], 0, len(counts)))[0]
    batch = [jnp.asarray(x)[idx] for x in data]
    model = trainer.model(trainer.init(jax.random.key(0)).params)
    assert_packed_equals_dense(model, batch, cap)
    with pytest.raises(ValueError, match="packed_pairs"):
        train.make_train(small_cfg("trex"), packed_pairs=64)


TWO_DEVICES = textwrap.dedent(
    """
    import json, sys
    import numpy as np, jax
    import slotv_jax
    from slotv_jax.training import config as train_config
    from slotv_jax.training import trainer as train
    sys.path.insert(0, {tests!r})
    from test_train import synthetic_split
    assert jax.device_count() == 2, jax.devices()
    split = synthetic_split(0, 160)
    data = train.prepare(split, "effdist")
    out = {{}}
    for method in ("slotv", "trex"):
        cfg = train_config.quick(method, hidden=(16, 8), batch_size=16, epochs=2, train_size=None)
        res = {{}}
        for n in (1, 2):
            mesh = train.make_mesh(cfg.batch_size, jax.devices()[:n])
            trainer = train.make_train(cfg, mesh=mesh, progress=False)
            assert trainer.mesh.size == n
            state, _ = jax.jit(trainer.train)(jax.random.key(5), trainer.replicate(data))
            leaf = jax.tree.leaves(state.params)[1]
            res[n] = [np.asarray(x).tolist() for x in jax.tree.leaves(state.params)]
            res[f"devices{{n}}"] = len(leaf.sharding.device_set)
            model = trainer.model(state.params)
            p = jax.nn.softmax(model(data.xyz[:64], data.goals[:64], data.goal_mask[:64]))
            res[f"probs{{n}}"] = np.asarray(p).tolist()
        out[method] = res
    print("RESULT" + json.dumps(out))
    """
)


@pytest.mark.slow
def test_one_and_two_devices_give_the_same_params():
    """The batch axis sharded over 2 CPU devices gives the 1-device result (fresh process,
    so the device-count flag applies before JAX starts; slotv_jax appends its own flag)."""
    env = dict(os.environ)
    env["XLA_FLAGS"] = (
        env.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=2"
    ).strip()
    code = TWO_DEVICES.format(tests=os.path.dirname(__file__))
    r = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300
    )
    assert r.returncode == 0, r.stderr[-3000:]
    out = json.loads(r.stdout.split("RESULT", 1)[1])
    for method in ("slotv", "trex"):
        res = out[method]
        assert res["devices1"] == 1 and res["devices2"] == 2
        cfg = train_config.quick(method)  # the subprocess's learning rate
        assert_same_run(
            cfg, res["1"], res["2"], np.asarray(res["probs1"]), np.asarray(res["probs2"])
        )


# ------------------------------------------------------------- in-loop validation, progress


@pytest.mark.slow
def test_eval_every_k_updates(tiny):
    tr, te = tiny
    data = types.prepare(tr, "effdist")
    val = types.prepare(te, "effdist")
    # 10 updates per epoch, k = 3: validations after 3, 6, 9 updates of each epoch, then a tail
    cfg = small_cfg("slotv", epochs=2, train_size=160, eval_every=3, eval_size=50)
    _, metrics = train.train_trials(cfg, data, [0], val=val, progress=False)
    np.testing.assert_array_equal(metrics.eval_updates[0], [[3, 6, 9], [13, 16, 19]])
    acc = np.asarray(metrics.eval_accuracy[0])
    assert acc.shape == (2, 3) and np.all((acc >= 0) & (acc <= 1))
    np.testing.assert_allclose(acc * 50, np.round(acc * 50), atol=1e-4)  # out of 50
    assert metrics.loss.shape == (1, 2, 4)  # 3 blocks + the 1-update tail per epoch

    # k = 5 divides the epoch: the last validation sees the final parameters
    cfg = dataclasses.replace(cfg, eval_every=5)
    states, metrics = train.train_trials(cfg, data, [0], val=val, progress=False)
    np.testing.assert_array_equal(metrics.eval_updates[0], [[5, 10], [15, 20]])
    sub = types.subset(val, 50)
    final = evaluate.accuracy(cfg, train.select_trial(states.params, 0), sub)
    assert float(metrics.eval_accuracy[0, -1, -1]) == pytest.approx(float(final), abs=1e-6)
    init = train.make_train(cfg, progress=False).init(jax.random.key(0))
    start = evaluate.accuracy(cfg, init.params, sub)
    assert float(metrics.start_accuracy[0]) == pytest.approx(float(start), abs=1e-6)


def test_progress_reaches_the_host(tiny):
    tr, _ = tiny
    cfg = small_cfg("slotv", epochs=2, train_size=160, log_every=4)
    seen = []

    class Spy(train._Progress):
        def __call__(self, updates, loss, *, total):
            seen.append((int(np.max(updates)), total, float(np.mean(loss))))
            return super().__call__(updates, loss, total=total)

    spy = Spy("test", cfg.batch_size)
    trainer = dataclasses.replace(train.make_train(cfg, progress=True), progress=spy)
    _, metrics = jax.jit(trainer.train)(jax.random.key(0), types.prepare(tr, "effdist"))
    jax.block_until_ready(metrics)
    # 10 updates per epoch in blocks of 4: reports after 4, 8, 10 | 14, 18, 20
    assert [u for u, _, _ in seen] == [4, 8, 10, 14, 18, 20]
    assert all(t == 20 for _, t, _ in seen) and spy.last == 20 and spy.bar is None
    np.testing.assert_allclose([v for _, _, v in seen], np.ravel(metrics.loss), rtol=1e-6)


def test_train_trials_shows_its_bar_before_it_compiles(tiny, monkeypatch):
    """The training bar opens before the compiled call and says that it compiles (the
    first call: a quiet minute on a loaded CPU, inside Table 1's first cell), then runs to
    its total; a second call with the same shapes only starts."""
    tr, _ = tiny
    cfg = small_cfg("trex", epochs=1, train_size=64, log_every=2, hidden=(20, 4))  # its own
    bars = []

    class Bar:  # a tqdm that records what it was shown
        def __init__(self, total, **kw):
            self.total, self.n, self.notes = total, 0, []
            bars.append(self)

        def set_postfix_str(self, s, refresh=True):
            self.notes.append(s)

        def set_postfix(self, refresh=True, **kw):
            self.notes.append(kw)

        def update(self, n):
            self.n += n

        def close(self):
            pass

    monkeypatch.setattr(train, "tqdm", Bar)
    data = types.prepare(tr, "effdist")
    with backend_compiles() as compiled:
        train.train_trials(cfg, data, [0], progress=True)
        # jit's executable cache is shared by the whole process and drops entries late in a
        # long one (as here): the trainer keeps its own compiled program
        train._jit_trials(train.make_train(cfg, progress=True), False).clear_cache()
        train.train_trials(cfg, data, [1], progress=True)
    assert compiled.count("jit(train)") == 1
    assert [b.notes[0] for b in bars] == ["compiling the training step", "starting"]
    assert [b.n for b in bars] == [b.total for b in bars] == [64, 64]  # 4 updates of 16
    assert all(set(b.notes[1]) == {"loss"} for b in bars)  # the loss replaced the note


def test_training_compiles_once_per_config(tiny):
    tr, _ = tiny
    cfg = small_cfg("trex", epochs=1, train_size=64, hidden=(18, 6))  # its own programs
    a = types.prepare(tr, "effdist")
    b = types.make_data(
        tr.xyz[::-1], tr.goals[::-1], tr.goal_mask[::-1], tr.labels["effdist"][::-1]
    )
    slots = [types.trim_goals(types.subset(d, 64)).goals.shape for d in (a, b)]
    assert slots[0] == slots[1]  # the same shapes after cutting unused goal slots
    with backend_compiles() as compiled:
        train.train_trials(cfg, a, 2, progress=False)
        train.train_trials(cfg, b, [5, 6], progress=False)
        train.train_trials(cfg, a, [1], progress=False)  # one trial: the unbatched function
        train.train_trials(cfg, b, [2], progress=False)
    trainer = train.make_train(cfg, progress=False)
    kept = [k for k in train._PROGRAMS if k[0] is trainer]
    assert sorted(k[1] for k in kept) == [False, True]  # one program with a trial axis, one not
    assert compiled.count("jit(train)") == 2  # each compiled once, by its first call


def test_precompile_is_reused_by_train_trials(tiny):
    """A training function compiled from shapes alone is the one train_trials runs: no
    second compilation of it, and the same result as a run compiled on the spot."""
    tr, _ = tiny
    cfg = small_cfg("trex", epochs=1, train_size=48, hidden=(24, 8))
    data = types.prepare(tr, "effdist")
    g = types.trim_goals(types.subset(data, 48)).goals.shape[1]
    with backend_compiles() as compiled:
        assert train.precompile(cfg, len(data.xyz), data.xyz.shape[1], g)
        assert compiled.count("jit(train)") == 1
        state, _ = train.train_trials(cfg, data, [3], progress=False)
        assert compiled.count("jit(train)") == 1  # reused
    train._jit_trials.cache_clear()  # compile again on the spot: same parameters
    again, _ = train.train_trials(cfg, data, [3], progress=False)
    for x, y in zip(jax.tree.leaves(state.params), jax.tree.leaves(again.params), strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    # Packed SLOT-V updates depend on the data's batches: nothing to compile ahead on a CPU.
    slotv = small_cfg("slotv", epochs=1, train_size=48)
    expected = not train.packs_updates(jax.default_backend())
    assert train.precompile(slotv, len(data.xyz), data.xyz.shape[1], g) is expected


# ------------------------------------------------------------- evaluation


def test_accuracy_matches_numpy_and_breaks_ties_low():
    rng = np.random.default_rng(0)
    n = 37
    counts = rng.choice([2, 3, 5, 6], n)
    mask = np.arange(8)[None] < counts[:, None]
    scores = np.where(mask, rng.normal(size=(n, 8)), 100.0).astype(np.float32)  # padding high
    labels = np.where(mask, rng.uniform(0.1, 1, (n, 8)), 0)
    labels /= labels.sum(-1, keepdims=True)
    scores[0, :2] = 5.0  # tie in the scores -> slot 0
    labels[1, :2] = 0.5  # tie in the labels -> slot 0
    labels[1, 2:] = 0
    scores[1, :2] = [5.0, 5.0]
    pred = np.asarray(evaluate.predict(jnp.asarray(scores), jnp.asarray(mask)))
    tgt = np.asarray(evaluate.target(jnp.asarray(labels), jnp.asarray(mask)))
    ref_pred = np.argmax(np.where(mask, scores, -np.inf), -1)
    ref_tgt = np.argmax(np.where(mask, labels, -np.inf), -1)
    np.testing.assert_array_equal(pred, ref_pred)
    np.testing.assert_array_equal(tgt, ref_tgt)
    assert pred[0] == 0 and tgt[1] == 0 and pred[1] == 0


def test_chunked_accuracy_covers_the_whole_split_once(tiny):
    """Chunked, padded evaluation equals a plain per-trajectory NumPy count."""
    _, te = tiny
    cfg = small_cfg("slotv", eval_chunk=16)  # 200 = 12 chunks + 8 (padded)
    trainer = train.make_train(cfg, progress=False)
    state = trainer.init(jax.random.key(1))
    acc = float(evaluate.accuracy(cfg, state.params, te, "effdist"))
    model = trainer.model(state.params)
    logits = np.asarray(model(te.xyz, te.goals, te.goal_mask))
    ref = np.mean(
        np.argmax(logits, -1) == np.argmax(np.where(te.goal_mask, te.labels["effdist"], -1), -1)
    )
    assert acc == pytest.approx(ref, abs=1e-7)
    assert 0.0 < acc < 1.0


# ------------------------------------------------------------- validation at the boundary


def test_prepare_rejects_bad_inputs(tiny):
    tr, _ = tiny
    y = tr.labels["effdist"]
    ok = (tr.xyz, tr.goals, tr.goal_mask, y)
    types.make_data(*ok)
    bad_xyz = tr.xyz.copy()
    bad_xyz[2, 5, 0] = np.nan
    with pytest.raises(ValueError, match="xyz: expected finite"):
        types.make_data(bad_xyz, *ok[1:])
    with pytest.raises(ValueError, match="xyz"):
        types.make_data(tr.xyz[:, :, :2], *ok[1:])
    no_goal = tr.goal_mask.copy()
    no_goal[3] = False
    with pytest.raises(ValueError, match=r"goal_mask.*none"):
        types.make_data(tr.xyz, tr.goals, no_goal, np.where(no_goal, y, 0))
    with pytest.raises(ValueError, match=r"labels.*sum to 1"):
        types.make_data(*ok[:3], y * 0.5)
    neg = y.copy()
    neg[0, 0] = -0.1
    neg[0, 1] += 0.1
    with pytest.raises(ValueError, match=r"labels.*>= 0"):
        types.make_data(*ok[:3], neg)
    pad = y.copy()
    pad[0, 7] = 0.01 if not tr.goal_mask[0, 7] else 0
    with pytest.raises(ValueError, match=r"labels.*padded"):
        types.make_data(*ok[:3], pad)
    with pytest.raises(ValueError, match="labeler"):
        types.prepare(tr, "dragan")
    with pytest.raises(ValueError, match="no full batch"):
        cfg = small_cfg("slotv", batch_size=64, train_size=32)
        train.train_trials(cfg, types.prepare(tr, "effdist"), 1, progress=False)


# ------------------------------------------------------------- training on answers (CLI)

STUDY_COMBOS = [("mlp", "slotv"), ("mlp", "trex"), ("dragan", "slotv"), ("viewpoint", "slotv"),
                ("mixture", "slotv")]  # fmt: skip


@pytest.fixture(scope="module")
def study_file(tmp_path_factory):
    """A tiny simulated Dragan study (β = 20) with answers at τ = 0.3, 0.6 and 1."""
    from slotv_jax.answers import simulate, storage

    s = synthetic_split(7, 40, name="study")
    study = simulate.simulate_study(jax.random.key(0), s.xyz, s.goals, s.goal_mask, 4,
                                    beta=20.0, taus=(0.3, 0.6, 1.0))  # fmt: skip
    assert np.any(study.seen() < T) and np.any(study.seen() == T)
    path = tmp_path_factory.mktemp("study") / "study.npz"
    storage.save_study(path, study)
    return path, study


@pytest.mark.parametrize(("model", "method"), STUDY_COMBOS)
def test_cli_trains_every_model_on_a_study(study_file, tmp_path, capsys, model, method):
    """python -m slotv_jax.train --study FILE --model M --method X, for every combination the
    command offers; the checkpoint's training metrics are those of the loaded observer's
    prefix logits on every answer row (each row scored on the points its people saw)."""
    from slotv_jax.answers import crossval

    path, study = study_file
    out = tmp_path / "ck"
    argv = ["--study", str(path), "--model", model, "--method", method, "--out", str(out),
            "--epochs", "2", "--no-progress"]  # fmt: skip
    if model == "mlp":
        argv += ["--set", "hidden=8,4"]
    assert train_cli.main(argv) == 0
    printed = capsys.readouterr().out
    assert "epoch 2/2" in printed and "NLL per answer" in printed
    # the printed config names only what this model and its optimiser read; the stored one all
    shown = json.loads(next(ln for ln in printed.splitlines() if ln.startswith("config: "))[8:])
    stored = json.loads((out / "config.json").read_text())["config"]
    # every field but the camera, which only the motion reader's dict stores
    fields = {f.name for f in dataclasses.fields(train_config.TrainConfig)}
    assert set(stored) == fields - ({"camera"} if stored["model"] != "reader" else set())
    unused = {"adam": {"rho", "momentum"}, "rmsprop": {"b1", "b2"}}[stored["optimizer"]]
    if model != "mlp":  # an archetype has no network
        unused |= {"hidden", "activation", "start_term", "time_weight", "compute_dtype"}
    assert set(shown) == set(stored) - unused
    assert all(shown[k] == stored[k] for k in shown)
    meta = json.loads((out / "config.json").read_text())["meta"]
    obs = slotv_jax.load_observer(out, model=model)
    tr = study.answer_trajectory
    logits = jax.jit(jax.vmap(obs.prefix))(study.xyz[tr], study.goals[tr], study.goal_mask[tr],
                                           jnp.asarray(study.seen()))  # fmt: skip
    got = crossval.row_metrics(np.asarray(logits), study.goal_mask[tr], study.counts)
    want = meta["train_metrics"]
    assert got["nll_per_answer"] == pytest.approx(want["nll_per_answer"], rel=1e-5)
    assert got["accuracy"] == pytest.approx(want["accuracy"])
    if model != "mlp":  # an archetype: its fitted parameters, stored and in words
        assert meta["parameters"] == pytest.approx(obs.parameters())
        assert obs.describe().splitlines()[0] in printed


def test_cli_refuses_an_archetype_with_trex(study_file, tmp_path, capsys):
    path, _ = study_file
    with pytest.raises(SystemExit) as e:
        train_cli.main(["--study", str(path), "--model", "dragan", "--method", "trex",
                        "--out", str(tmp_path / "ck")])  # fmt: skip
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: method:") and "'slotv'" in err[0]
    assert not (tmp_path / "ck").exists()


def test_cli_checks_every_split_before_training(tiny_data, tiny_cfg, tmp_path, capsys):
    """A dataset folder without the test splits: the error comes before the first epoch,
    names the missing split, and nothing is written."""
    from slotv_jax import data as data_lib

    (tmp_path / "data").mkdir()
    for name in ("train", "trajectory_test"):
        data_lib.save_split(tmp_path / "data", tiny_data[name], tiny_cfg)
    ck = tmp_path / "ck"
    with pytest.raises(SystemExit) as e:
        train_cli.main(["--data", str(tmp_path / "data"), "--labeler", "effdist", "--method",
                        "slotv", "--out", str(ck), "--set", "hidden=8,4", "--epochs", "1",
                        "--no-progress"])  # fmt: skip
    assert e.value.code == 2
    cap = capsys.readouterr()
    err = cap.err.strip().splitlines()
    assert len(err) == 1 and "position_test" in err[0] and err[0].startswith("error:"), err
    assert "epoch" not in cap.out and not ck.exists()


def test_cli_init_starts_from_a_checkpoint_and_refuses_another(study_file, tmp_path, capsys):
    """train --init CKPT (:ref:`concepts-pick`): the run starts from the checkpoint's parameters
    (with a learning rate of 1e-12 the fine-tuned ones stay the checkpoint's, while the same run
    without --init ends far from them), and records where it started. Another observer,
    method or network shape, or no checkpoint, is one line before any work."""
    path, _ = study_file
    base = ["--study", str(path), "--epochs", "1", "--no-progress", "--set", "hidden=8,4"]
    start = tmp_path / "start"
    assert train_cli.main([*base, "--method", "slotv", "--out", str(start)]) == 0
    slow = [*base, "--method", "slotv", "--seed", "3", "--set", "learning_rate=1e-12"]
    assert train_cli.main([*slow, "--init", str(start), "--out", str(tmp_path / "tuned")]) == 0
    assert train_cli.main([*slow, "--out", str(tmp_path / "fresh")]) == 0
    params = {n: jax.tree.leaves(checkpoint.restore(tmp_path / n)[1].params)
              for n in ("start", "tuned", "fresh")}  # fmt: skip
    for a, b in zip(params["start"], params["tuned"], strict=True):
        np.testing.assert_allclose(np.asarray(b), np.asarray(a), rtol=0, atol=1e-6)
    gap = max(float(np.abs(np.asarray(a) - np.asarray(c)).max())
              for a, c in zip(params["start"], params["fresh"], strict=True))  # fmt: skip
    assert gap > 1e-2  # a random draw is far from the checkpoint's parameters
    assert checkpoint.restore(tmp_path / "tuned")[2]["init"] == str(start)
    capsys.readouterr()
    for extra, message in (
        (["--model", "dragan", "--method", "slotv"], "holds a 'mlp' observer, not the requested "
         "'dragan'"),
        (["--method", "trex"], "trained by 'slotv', not the requested 'trex'"),
        (["--method", "slotv", "--set", "hidden=16,8"], "other shapes than the requested 'mlp' "
         "observer's; the configs differ in hidden (saved [8, 4], requested [16, 8])"),
    ):  # fmt: skip
        out = tmp_path / "refused"
        with pytest.raises(SystemExit) as e:
            train_cli.main([*base, *extra, "--init", str(start), "--out", str(out)])
        err = capsys.readouterr().err.strip().splitlines()
        assert e.value.code == 2 and len(err) == 1, err
        assert err[0].startswith(f"error: --init {start}: ") and message in err[0], err
        assert not out.exists()
    with pytest.raises(SystemExit):
        train_cli.main([*base, "--method", "slotv", "--init", str(tmp_path / "none"),
                        "--out", str(tmp_path / "refused")])  # fmt: skip
    assert "no checkpoint there" in capsys.readouterr().err
