"""Tests for slotv_jax.training.checkpoint: save → load → identical logits, exact resume, clear
errors for mismatched checkpoints, and the loaded observer under jit, vmap and grad (checked
against central finite differences in float64)."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_train import synthetic_split

import slotv_jax
from slotv_jax.training import checkpoint, types
from slotv_jax.training import config as train_config
from slotv_jax.training import trainer as train

FD_TOL = 1e-6  # float64 directional derivative against central differences (relative)
F32_GRAD_TOL = 1e-3  # float32 gradient against the float64 one (relative to its norm)


@pytest.fixture(scope="module")
def split():
    return synthetic_split(3, 96)


def cfg_for(method, **kw):
    return train_config.quick(
        method, **{"hidden": (16, 8), "batch_size": 16, "epochs": 2, "train_size": None, **kw}
    )


def one_epoch(trainer):
    return jax.jit(lambda s, d: trainer.run(s, d, epochs=1))


@pytest.mark.parametrize("method", ["slotv", "trex"])
def test_save_load_gives_identical_logits(tmp_path, split, method):
    cfg = cfg_for(method, epochs=1)
    trainer = train.make_train(cfg, progress=False)
    data = types.prepare(split, "effdist")
    state, _ = jax.jit(trainer.train)(jax.random.key(0), data)
    path = checkpoint.save(tmp_path / "ck", cfg, state, meta={"labeler": "effdist"})
    assert checkpoint.exists(path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ck"]  # no temporary left behind
    doc = json.loads((path / "config.json").read_text())
    assert doc["config"]["hidden"] == [16, 8] and doc["epoch"] == 1
    assert doc["meta"] == {"labeler": "effdist"}

    observer = slotv_jax.load_observer(path)
    model = trainer.model(state.params)
    for i in range(4):
        got = observer(split.xyz[i], split.goals[i], split.goal_mask[i])
        want = model(split.xyz[i], split.goals[i], split.goal_mask[i])
        np.testing.assert_array_equal(np.asarray(got), np.asarray(want))
    batched = jax.jit(jax.vmap(observer))(split.xyz[:8], split.goals[:8], split.goal_mask[:8])
    np.testing.assert_allclose(
        batched, model(split.xyz[:8], split.goals[:8], split.goal_mask[:8]), rtol=1e-6
    )
    assert np.all(np.isneginf(np.asarray(batched)[~split.goal_mask[:8]]))

    # overwriting is atomic and replaces the content
    checkpoint.save(path, cfg, state, meta={"labeler": "effdist", "run": 2})
    assert checkpoint.restore(path)[2]["run"] == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ck"]


@pytest.mark.parametrize("method", ["slotv", "trex"])
def test_resume_continues_exactly(tmp_path, split, method):
    cfg = cfg_for(method)
    trainer = train.make_train(cfg, progress=False)
    data = types.prepare(split, "effdist")
    step = one_epoch(trainer)
    s0 = trainer.init(jax.random.key(4))
    s1, _ = step(s0, data)
    s2, _ = step(s1, data)

    checkpoint.save(tmp_path / "ck", cfg, s1)
    cfg_r, r1, _ = checkpoint.restore(tmp_path / "ck", cfg)
    assert cfg_r == cfg and int(r1.epoch) == 1
    r2, _ = step(r1, data)
    for a, b in zip(jax.tree.leaves(s2), jax.tree.leaves(r2), strict=True):
        if jnp.issubdtype(a.dtype, jax.dtypes.prng_key):
            a, b = jax.random.key_data(a), jax.random.key_data(b)
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))

    # and the per-epoch driver equals the pure two-epoch train()
    full, _ = jax.jit(trainer.train)(jax.random.key(4), data)
    for a, b in zip(jax.tree.leaves(full.params), jax.tree.leaves(s2.params), strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=0, atol=1e-6)


def test_mismatched_checkpoints_fail_clearly(tmp_path, split):
    cfg = cfg_for("slotv", epochs=1)
    trainer = train.make_train(cfg, progress=False)
    state = trainer.init(jax.random.key(0))
    path = checkpoint.save(tmp_path / "ck", cfg, state)

    # the stored config says another architecture than the stored arrays
    doc = json.loads((path / "config.json").read_text())
    doc["config"]["hidden"] = [16, 16]
    (path / "config.json").write_text(json.dumps(doc))
    with pytest.raises(ValueError, match=r"does not fit the model.*hidden=\(16, 16\)"):
        slotv_jax.load_observer(path)

    # resuming with a different architecture or method than the checkpoint's
    path = checkpoint.save(tmp_path / "ck", cfg, state)
    with pytest.raises(ValueError, match=r"hidden \(saved \[16, 8\], requested \[32, 8\]\)"):
        checkpoint.restore(path, cfg_for("slotv", hidden=(32, 8)))
    with pytest.raises(ValueError, match="method"):
        checkpoint.restore(path, cfg_for("trex"))
    checkpoint.restore(path, cfg_for("slotv", epochs=9))  # more epochs is fine

    # saving a state that the config does not describe
    other = train.make_train(cfg_for("slotv", hidden=(8, 8)), progress=False)
    with pytest.raises(ValueError, match="does not fit"):
        checkpoint.save(tmp_path / "bad", cfg, other.init(jax.random.key(0)))
    assert not (tmp_path / "bad").exists()

    with pytest.raises(FileNotFoundError, match="nowhere: does not exist"):
        slotv_jax.load_observer(tmp_path / "nowhere")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="not a slotv_jax checkpoint"):
        slotv_jax.load_observer(tmp_path / "empty")


@pytest.mark.parametrize("method", ["slotv", "trex"])
def test_observer_gradient_matches_finite_differences(tmp_path, split, method):
    cfg = cfg_for(method, epochs=1)
    trainer = train.make_train(cfg, progress=False)
    state, _ = jax.jit(trainer.train)(jax.random.key(1), types.prepare(split, "effdist"))
    path = checkpoint.save(tmp_path / "ck", cfg, state)
    observer = slotv_jax.load_observer(path)
    xyz, goals, mask = split.xyz[5], split.goals[5], split.goal_mask[5]
    k = int(np.argmax(split.labels["effdist"][5]))

    def prob(obs, x):
        return jax.nn.softmax(obs(x, goals, mask))[k]

    g32 = jax.jit(jax.grad(lambda x: prob(observer, x)))(xyz)
    assert g32.shape == (100, 3) and np.all(np.isfinite(np.asarray(g32)))
    assert np.linalg.norm(np.asarray(g32)) > 0

    with jax.enable_x64(True):
        cfg_l, st, _ = checkpoint.restore(path)
        p64 = jax.tree.map(lambda a: jnp.asarray(a, jnp.float64), st.params)
        obs64 = checkpoint.make_observer(cfg_l, p64)
        x64 = jnp.asarray(xyz, jnp.float64)
        g64 = np.asarray(jax.grad(lambda x: prob(obs64, x))(x64))
        assert g64.dtype == np.float64
        rng = np.random.default_rng(0)
        for _ in range(3):
            v = rng.normal(size=xyz.shape)
            v /= np.linalg.norm(v)
            h = 1e-4  # the ReLU net is piecewise linear: small, but well above rounding
            fd = (prob(obs64, x64 + h * v) - prob(obs64, x64 - h * v)) / (2 * h)
            assert float(fd) == pytest.approx(float(np.sum(g64 * v)), rel=FD_TOL, abs=1e-12)
    err = np.linalg.norm(np.asarray(g32, np.float64) - g64) / np.linalg.norm(g64)
    assert err < F32_GRAD_TOL, err


def test_observer_rejects_bad_inputs(tmp_path, split):
    cfg = cfg_for("slotv", epochs=1)
    state = train.make_train(cfg, progress=False).init(jax.random.key(0))
    observer = slotv_jax.load_observer(checkpoint.save(tmp_path / "ck", cfg, state))
    xyz, goals, mask = split.xyz[0], split.goals[0], split.goal_mask[0]
    with pytest.raises(ValueError, match="xyz"):
        observer(xyz[None], goals, mask)  # batch with vmap instead
    with pytest.raises(ValueError, match="goal_mask"):
        observer(xyz, goals, np.zeros(8, bool))
    bad = goals.copy()
    bad[0, 0] = np.inf
    with pytest.raises(ValueError, match="goals: expected finite"):
        observer(xyz, bad, mask)


# ------------------------------------------------------------- errors name file and field

BAD_CONFIG = [
    ("hidden", "abc", "expected a list of positive integers"),
    ("hidden", [16, "8"], "expected a list of positive integers"),
    ("hidden", [16, 0], "positive ints"),
    ("model", "xyz", "expected one of"),
    ("method", "reinforce", "expected one of"),
    ("epochs", "3", "expected an integer"),
    ("learning_rate", -1.0, "expected a finite number > 0"),
    ("start_term", 1, "expected true or false"),
    ("hiden", [16, 8], "not a training config field"),
]


@pytest.mark.parametrize(("field", "value", "text"), BAD_CONFIG)
def test_bad_config_names_the_file_and_field(tmp_path, field, value, text):
    cfg = cfg_for("slotv", epochs=1)
    path = checkpoint.save(tmp_path / "ck", cfg, train.make_train(cfg).init(jax.random.key(0)))
    doc = json.loads((path / "config.json").read_text())
    doc["config"][field] = value
    (path / "config.json").write_text(json.dumps(doc))
    where = str(path / "config.json")
    for load in (slotv_jax.load_observer, checkpoint.load_config):
        with pytest.raises(ValueError) as e:
            load(path)
        msg = str(e.value)
        assert msg.startswith(f"{where}: field 'config.{field}': ") and text in msg, msg
    doc["config"] = [1, 2]
    (path / "config.json").write_text(json.dumps(doc))
    with pytest.raises(ValueError, match=rf"^{re.escape(where)}: field 'config': expected an obj"):
        slotv_jax.load_observer(path)
    with pytest.raises(ValueError, match="model: expected one of"):
        slotv_jax.load_observer(path, model="nope")


def test_loading_prints_nothing(tmp_path):
    """Five checkpoints loaded in one process, and two truncated ones refused: nothing on
    stderr. (Before: every read still in flight when Orbax closed its event loop after a
    failed restore printed a "RuntimeError: Event loop is closed" traceback, tens of them.)"""
    cfg = cfg_for("slotv", epochs=1)
    state = train.make_train(cfg).init(jax.random.key(0))
    good = [checkpoint.save(tmp_path / f"ck{i}", cfg, state) for i in range(5)]
    bad = []
    for i, keep in enumerate((0.5, -1)):
        ck = shutil.copytree(good[0], tmp_path / f"bad{i}")
        # every data file: which one holds the parameters (all that loading reads) varies
        # from save to save, so cutting only the largest one let a load pass once in CI
        for data in (ck / "state").rglob("d/*"):
            if keep < 0:
                data.unlink()
            else:
                data.write_bytes(data.read_bytes()[: len(data.read_bytes()) // 2])
        bad.append(ck)
    script = textwrap.dedent(f"""
        import gc, time
        import slotv_jax
        good, bad = {[str(p) for p in good]!r}, {[str(p) for p in bad]!r}
        for p in good:
            slotv_jax.load_observer(p)
        for p in bad * 3:
            try:
                slotv_jax.load_observer(p)
            except ValueError as e:
                assert "truncated or corrupt" in str(e), e
            else:
                raise SystemExit("a truncated checkpoint loaded")
        gc.collect()
        time.sleep(1.0)  # late reads of the refused checkpoints report now, if at all
        print("ok")
    """)
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                       timeout=300)  # fmt: skip
    assert r.returncode == 0 and r.stdout.strip().endswith("ok"), r.stderr[-2000:]
    assert r.stderr == "", r.stderr[-2000:]
