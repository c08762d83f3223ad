"""Tests for slotv_jax.training.parallel: the group plan, runs side by side on 4 CPU devices (one
per device, no communication, the same parameters as training one after another), per-run labels,
padded and batch-parallel groups, and the one-job-per-device dispatcher.

The multi-device checks run in a fresh process with
``XLA_FLAGS=--xla_force_host_platform_device_count=4`` (the flag must be set before JAX
starts; slotv_jax appends its own CPU flag and keeps the user's)."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest

import slotv_jax  # noqa: F401  (applies the XLA CPU setting before JAX starts)
from slotv_jax.training import parallel, schedule

COLLECTIVES = ("all-reduce", "all-gather", "collective-permute", "all-to-all", "reduce-scatter")


def test_plan_hand_cases():
    assert schedule.group_sizes(10, 4) == [(4, 4), (4, 4), (2, 2)]  # 10 trials on 4 devices
    assert schedule.group_sizes(8, 4) == [(4, 4), (4, 4)]
    assert schedule.group_sizes(3, 4) == [(3, 4)]  # padded to 4, one run per device
    assert schedule.group_sizes(1, 4) == [(1, 1)]  # one run: its batch over all 4 devices
    assert schedule.group_sizes(5, 6) == [(5, 6)]
    assert schedule.group_sizes(4, 6) == [(4, 6)]
    assert schedule.group_sizes(3, 6) == [(3, 3)]  # two devices per run
    assert schedule.group_sizes(3, 1) == [(1, 1)] * 3  # one device: one unit at a time
    assert schedule.group_sizes(0, 4) == []
    assert schedule.groups(list("abcde"), 2) == [(["a", "b"], 2), (["c", "d"], 2), (["e"], 1)]
    with pytest.raises(ValueError, match="n_devices"):
        schedule.group_sizes(3, 0)
    with pytest.raises(ValueError, match="seeds"):
        parallel.seeds_array([1, -2])


FOUR_DEVICES = textwrap.dedent(
    """
    import sys
    import numpy as np, jax, jax.numpy as jnp
    from jax.sharding import NamedSharding, PartitionSpec as P
    import slotv_jax
    from slotv_jax.training import evaluate, parallel, schedule
    from slotv_jax.training import trainer as train
    sys.path.insert(0, {tests!r})
    from compile_log import backend_compiles
    from test_train import assert_same_run, effdist_np, probabilities, small_cfg, synthetic_split
    assert jax.device_count() == 4, jax.devices()
    split = synthetic_split(0, 320)
    data = train.prepare(split, "effdist")
    one = jax.devices()[:1]
    COLLECTIVES = {collectives!r}

    def sequential(cfg, seeds, d=data):
        mesh = train.make_mesh(cfg.batch_size, one)
        return train.train_trials(cfg, d, seeds, mesh=mesh, progress=False)[0].params

    def check_same(cfg, params, ref, d=data):
        for i in range(len(jax.tree.leaves(ref)[0])):
            a = jax.tree.map(lambda x: np.asarray(x)[i], params)
            b = jax.tree.map(lambda x: np.asarray(x)[i], ref)
            assert_same_run(cfg, a, b, probabilities(cfg, a, d), probabilities(cfg, b, d))

    # 4 runs side by side, one per device, without communication; equal to one by one.
    for method in ("slotv",):
        cfg = small_cfg(method)
        mesh = schedule.unit_mesh(4, cfg.batch_size)
        assert dict(mesh.shape) == {{"trial": 4, "data": 1}}
        state, metrics = parallel.train_group(cfg, data, [0, 1, 2, 3], mesh)
        for leaf in jax.tree.leaves(state.params):
            assert leaf.sharding.spec[0] == "trial", leaf.sharding
            shards = leaf.addressable_shards
            assert sorted(s.device.id for s in shards) == [0, 1, 2, 3]
            assert all(s.data.shape == (1, *leaf.shape[1:]) for s in shards)
        trainer = train.make_train(cfg, mesh=mesh, progress=False)
        trainer = train.packed_trainer(
            trainer, jax.vmap(train.Trainer.state_key)(train.trial_keys(4)),
            train.trim_goals(data), range(cfg.epochs))
        hlo = parallel._jit_group(trainer, False, True).lower(
            jax.device_put(np.arange(4, dtype=np.int32), NamedSharding(mesh, P("trial"))),
            jax.device_put(train.trim_goals(data), NamedSharding(mesh, P())), None,
        ).compile().as_text()
        assert not [c for c in COLLECTIVES if c in hlo], "runs communicate"
        ref_params = sequential(cfg, [0, 1, 2, 3])
        check_same(cfg, state.params, ref_params)
        acc = parallel.group_accuracy(cfg, state.params, data, mesh)
        ref = evaluate.accuracy(cfg, ref_params, data, mesh=train.make_mesh(cfg.batch_size, one))
        np.testing.assert_array_equal(acc, ref)

    # Three runs with their own labels, padded to 4 devices; one run over all 4 devices.
    cfg = small_cfg("slotv")
    y = {{b: effdist_np(split.xyz.astype(np.float64), split.goals.astype(np.float64),
                        split.goal_mask, beta=b).astype(np.float32) for b in (2.0, 5.0, 20.0)}}
    labels = np.stack([y[20.0], y[2.0], y[5.0]])
    state, _ = parallel.train_group(cfg, data, [7, 8, 9], schedule.unit_mesh(4, 16), labels=labels)
    assert jax.tree.leaves(state.params)[0].shape[0] == 4  # padded: run 3 repeats run 2
    acc = parallel.group_accuracy(cfg, state.params, data, schedule.unit_mesh(4, 16), labels=labels)
    for i, (seed, b) in enumerate(zip([7, 8, 9], [20.0, 2.0, 5.0])):
        d = data._replace(labels=jnp.asarray(y[b]))
        mine = jax.tree.map(lambda x: x[i : i + 1], state.params)
        ref_params = sequential(cfg, [seed], d)
        check_same(cfg, mine, ref_params, d)
        ref = evaluate.accuracy(cfg, ref_params, d, mesh=train.make_mesh(16, one))
        np.testing.assert_array_equal(acc[i : i + 1], ref)
    mesh = schedule.unit_mesh(1, cfg.batch_size)
    assert dict(mesh.shape) == {{"trial": 1, "data": 4}}
    state, _ = parallel.train_group(cfg, data, [3], mesh)
    assert len(jax.tree.leaves(state.params)[1].sharding.device_set) == 4
    check_same(cfg, state.params, sequential(cfg, [3]))

    # Six runs with in-loop validation (sample efficiency): padded to 8, two per device.
    cfg = small_cfg("slotv", eval_every=4, eval_size=64, epochs=1, train_size=128)
    state, metrics = parallel.train_group(cfg, data, range(6), schedule.unit_mesh(4, 16), val=data)
    assert metrics.eval_accuracy.shape[0] == 8
    assert all(s.data.shape[0] == 2 for s in metrics.eval_accuracy.addressable_shards)
    ref_state, ref = train.train_trials(cfg, data, range(6), val=data, progress=False,
                                        mesh=train.make_mesh(16, one))
    assert ref.eval_accuracy.shape == (6, 1, 2)
    np.testing.assert_allclose(np.asarray(metrics.eval_accuracy)[:6], ref.eval_accuracy,
                               rtol=0, atol=2 / 64)  # a near tie may flip
    check_same(cfg, jax.tree.map(lambda x: x[:6], state.params), ref_state.params)

    # T-REX: a full group compiled from shapes alone is the one train_group runs (CPUs pack
    # only SLOT-V updates, whose compiled function depends on the data), equal one by one.
    cfg = small_cfg("trex", epochs=1, train_size=48, hidden=(24, 8))
    g = train.trim_goals(data).goals.shape[1]
    mesh = schedule.unit_mesh(4, cfg.batch_size)
    with backend_compiles() as compiled:
        assert parallel.precompile_group(cfg, len(data.xyz), data.xyz.shape[1], g, mesh)
        assert compiled.count("jit(train_run)") == 1
        labels4 = np.stack([np.asarray(data.labels)] * 4)
        state, _ = parallel.train_group(cfg, data, [0, 1, 2, 3], mesh, labels=labels4)
        assert compiled.count("jit(train_run)") == 1, compiled  # reused
    check_same(cfg, state.params, sequential(cfg, [0, 1, 2, 3]))

    # One job per device, dispatched asynchronously, results in job order.
    def start(job, device):
        x = jnp.full((2,), float(job))
        assert x.devices() == {{device}}  # placed by jax.default_device
        return x * 2
    got = list(parallel.map_on_devices(list(range(6)), start, 2))
    assert [j for j, _ in got] == list(range(6))
    assert all(np.array_equal(r, [2 * j, 2 * j]) for j, r in got)
    calls = []
    got = list(parallel.map_on_devices(list(range(9)), start, 2,
                                       keep_going=lambda: calls.append(1) or len(calls) < 2))
    assert [j for j, _ in got] == [0, 1, 2, 3]  # stopped before the third round of 4
    print("OK")
    """
)


@pytest.mark.slow
def test_runs_side_by_side_on_four_devices_equal_sequential_training():
    """4 runs train side by side, one per device, with no collective in the compiled
    program; each run's parameters (and accuracy) equal those of training it alone on one
    device; per-run labels, a padded group of 3 and a one-run batch-parallel group too."""
    env = dict(os.environ)
    env["XLA_FLAGS"] = (
        env.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=4"
    ).strip()
    code = FOUR_DEVICES.format(tests=os.path.dirname(__file__), collectives=COLLECTIVES)
    r = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300
    )
    assert r.returncode == 0, r.stderr[-4000:]
    assert r.stdout.strip().endswith("OK")
