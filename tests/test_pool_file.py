"""The researcher's pool as a folder (``slotv_jax.answers.pool_file``): written and read
back as the observer the people loop plans against, checked against a float64 NumPy
re-derivation of the log-linear pool, and every malformed ``pool.json`` refused in one line
naming the field before any member is loaded."""

from __future__ import annotations

import json
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from slotv_jax import planning
from slotv_jax.answers import PROB_FLOOR, load_pool, pool_observer, save_pool
from slotv_jax.answers.pick import fit_config
from slotv_jax.answers.pool_file import BETA_MAX, WEIGHT_SUM_MAX
from slotv_jax.observers import labelers
from slotv_jax.training import checkpoint
from slotv_jax.training import trainer as train
from slotv_jax.world.scene import camera as scene_camera

BETAS = {"dragan": 6.0, "nikolaidis": 3.5}


def _problem(seed: int = 0):
    """A smooth motion towards goal 1 of three (eight slots, five padded)."""
    rng = np.random.default_rng(seed)
    goals = np.zeros((8, 3), np.float32)
    goals[:3] = np.array([[0.5, -0.2, 0.1], [0.55, 0.1, 0.12], [0.45, 0.3, 0.1]]) + rng.normal(
        0, 0.01, (3, 3)
    )
    mask = np.arange(8) < 3
    t = np.linspace(0, 1, 30)[:, None]
    start = np.array([0.3, 0.0, 0.5])
    bend = np.sin(np.pi * t) * np.array([0.0, 0.08, 0.05])
    xyz = (start + t * (goals[1] - start) + bend).astype(np.float32)
    return xyz, goals, mask


def _learned_member():
    cfg = fit_config("quick", "dragan_archetype", 100)
    state = train.make_train(cfg, progress=False).init(jax.random.key(3))
    return {"cfg": cfg, "state": state}


def test_a_labeler_pool_is_the_normalised_weighted_product_float64(tmp_path):
    """P_w ∝ Π_f max(P_f, floor)^{w_f} on the real goals, 0 on the padded ones, for the
    whole motion and for a prefix; written and read back unchanged."""
    xyz, goals, mask = _problem()
    w = {"dragan": 0.7, "nikolaidis": 0.45}
    kept = save_pool(tmp_path / "p", {n: {"beta": b} for n, b in BETAS.items()}, w)
    assert kept == ["dragan", "nikolaidis"]
    obs = load_pool(tmp_path / "p")
    assert obs.config == ("dragan", "nikolaidis")
    np.testing.assert_array_equal(obs.params["weights"], np.float32([0.7, 0.45]))
    cam = scene_camera("observer")
    for seen in (12, 30):
        x = xyz[:seen]
        want = np.ones(8)
        for n, b in BETAS.items():
            kw = {"camera": cam} if n == "nikolaidis" else {}
            y = np.asarray(getattr(labelers, n)(x, goals, mask, beta=b, **kw), np.float64)
            want *= np.where(mask, np.maximum(y / y[mask].sum(), PROB_FLOOR), 1.0) ** w[n]
        want = np.where(mask, want, 0.0) / want[mask].sum()
        z = obs.prefix(jnp.asarray(xyz), jnp.asarray(goals), jnp.asarray(mask), seen)
        np.testing.assert_allclose(np.asarray(jax.nn.softmax(z), np.float64), want, atol=2e-6)
        assert np.all(np.isneginf(np.asarray(z)[~mask]))
        if seen == 30:
            whole = obs(jnp.asarray(xyz), jnp.asarray(goals), jnp.asarray(mask))
            np.testing.assert_allclose(np.asarray(jax.nn.softmax(whole)), want, atol=2e-6)


def test_a_pool_with_a_learned_member_reads_back_with_a_gradient(tmp_path):
    """A learned family's checkpoint under members/ and a labeler: the loaded pool equals
    the pool of the in-memory observers, members of weight 0 are not written, and its
    prefix objective (what :func:`slotv_jax.planning.make_planner` plans with) has a finite
    gradient."""
    fits = {
        "dragan_archetype": _learned_member(),
        "dragan": {"beta": 5.0},
        "nikolaidis": {"beta": 2.0},
    }
    w = {"dragan_archetype": 0.6, "dragan": 0.3, "nikolaidis": 0.0}
    assert save_pool(tmp_path / "p", fits, w, meta={"study": "s.npz"}) == [
        "dragan_archetype",
        "dragan",
    ]
    doc = json.loads((tmp_path / "p" / "pool.json").read_text())
    assert [m["name"] for m in doc["members"]] == ["dragan_archetype", "dragan"]
    assert doc["meta"] == {"study": "s.npz"} and checkpoint.exists(
        tmp_path / "p/members/dragan_archetype"
    )
    loaded = load_pool(tmp_path / "p")
    fit = fits["dragan_archetype"]
    direct = pool_observer(
        [
            checkpoint.make_observer(fit["cfg"], fit["state"].params),
            planning.labeler_observer("dragan", beta=5.0),
        ],
        [0.6, 0.3],
    )
    xyz, goals, mask = (jnp.asarray(a) for a in _problem(1))
    for seen in (10, 30):
        np.testing.assert_allclose(
            np.asarray(loaded.prefix(xyz, goals, mask, seen)),
            np.asarray(direct.prefix(xyz, goals, mask, seen)),
            atol=1e-6,
        )
    # what a planner differentiates: the prefix objective's gradient in xyz, finite
    g = jax.grad(lambda x: jax.nn.log_softmax(loaded.prefix(x, goals, mask, 20))[1])(xyz)
    assert g.shape == xyz.shape and bool(jnp.all(jnp.isfinite(g))) and float(jnp.abs(g).max()) > 0


def _write(tmp_path, doc) -> str:
    d = tmp_path / "bad"
    d.mkdir(exist_ok=True)
    (d / "pool.json").write_text(json.dumps(doc))
    return str(d)


def test_a_malformed_pool_is_refused_naming_the_field(tmp_path):
    good = {
        "format": "slotv_jax observer pool",
        "version": 1,
        "camera": "observer",
        "members": [{"name": "dragan", "weight": 0.5, "labeler": "dragan", "beta": 4.0}],
    }
    assert load_pool(_write(tmp_path, good)).config == ("dragan",)
    member = good["members"][0]
    cases = [
        ({**good, "format": "x"}, "field 'format': expected 'slotv_jax observer pool'"),
        ({**good, "version": 2}, "field 'version': expected 1"),
        ({**good, "camera": "top"}, "field 'camera': expected one of"),
        ({**good, "members": []}, "field 'members': expected a non-empty list"),
        (
            {**good, "members": [{**member, "weight": -1}]},
            r"members\[0\]\.weight': expected a number in",
        ),
        ({**good, "members": [{**member, "weight": True}]}, r"members\[0\]\.weight'"),
        ({**good, "members": [{**member, "beta": float("nan")}]}, "not valid JSON|beta"),
        (
            {**good, "members": [{**member, "labeler": "effdist"}]},
            r"members\[0\]\.labeler': expected one of",
        ),
        ({**good, "members": [{**member, "checkpoint": "members/x"}]}, "either 'checkpoint' or"),
        (
            {**good, "members": [{"name": "m", "weight": 1, "checkpoint": "../elsewhere"}]},
            r"members\[0\]\.checkpoint': expected a folder inside",
        ),
        (
            {**good, "members": [{"name": "m", "weight": 1, "checkpoint": "members/m"}]},
            r"members\[0\]\.checkpoint': no checkpoint at",
        ),
    ]
    for doc, needle in cases:
        with pytest.raises(ValueError, match=needle):
            load_pool(_write(tmp_path, doc))
    (tmp_path / "bad" / "pool.json").write_text('{"format": ')
    with pytest.raises(ValueError, match=r"pool\.json, line 1.*not valid JSON"):
        load_pool(tmp_path / "bad")
    with pytest.raises(FileNotFoundError, match=r"no pool\.json"):
        load_pool(tmp_path)
    with pytest.raises(ValueError, match="all 0"):
        save_pool(tmp_path / "z", {"dragan": {"beta": 1.0}}, {"dragan": 0.0})
    assert not (tmp_path / "z").exists()
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("a user's file")
    with pytest.raises(ValueError, match="out: expected a new or empty folder"):
        save_pool(tmp_path / "mine", {"dragan": {"beta": 1.0}}, {"dragan": 1.0})
    assert [p.name for p in (tmp_path / "mine").iterdir()] == ["notes.txt"]


def test_a_pool_that_would_not_stay_finite_is_refused_at_load(tmp_path):
    """A weight of 1e300 (finite in float64, inf in float32: every probability NaN) or a
    labeler's β of 1e300 (its labels overflow at the first call) is refused by load_pool,
    naming the file, the member and the field, before any member is loaded; at the bounds
    (the weights summing to WEIGHT_SUM_MAX, β = BETA_MAX) the pool's probabilities are
    finite."""
    xyz, goals, mask = _problem()
    lab = planning.labeler_observer("dragan", beta=4.0)
    with np.errstate(over="ignore"):  # what it was: 1e300 is inf in float32
        nan = jax.nn.softmax(pool_observer([lab], [1e300])(xyz, goals, mask))
    assert np.isnan(np.asarray(nan)[mask]).all()

    def doc(w0=0.5, w1=0.5, b0=4.0, b1=3.5):
        return {"format": "slotv_jax observer pool", "version": 1, "camera": "observer",
                "members": [{"name": "dragan", "weight": w0, "labeler": "dragan", "beta": b0},
                            {"name": "nikolaidis", "weight": w1, "labeler": "nikolaidis",
                             "beta": b1}]}  # fmt: skip

    where = tmp_path / "bad" / "pool.json"
    cases = [
        (doc(w1=1e300), "members[1].weight': expected a number in [1.18e-38, 6.16e+36]"),
        (doc(b1=1e300), "members[1].beta': expected a number in [1.18e-38, 3.4e+31]"),
        (doc(w0=1e-300), "members[0].weight'"),
        (doc(b0=1e-300), "members[0].beta'"),
        (doc(w0=0.6 * WEIGHT_SUM_MAX, w1=0.6 * WEIGHT_SUM_MAX), "'members': the weights sum to"),
        ({**doc(), "members": doc()["members"][:1] * 2}, "members[1].name': expected distinct"),
        ({**doc(), "meta": [1]}, "field 'meta': expected an object"),
    ]
    for bad, needle in cases:
        with pytest.raises(ValueError, match="^" + re.escape(f"{where}: field '") + ".*"):
            load_pool(_write(tmp_path, bad))
        with pytest.raises(ValueError, match=re.escape(needle)):
            load_pool(_write(tmp_path, bad))
    edge = load_pool(_write(tmp_path, doc(0.5 * WEIGHT_SUM_MAX, 0.5 * WEIGHT_SUM_MAX, BETA_MAX)))
    for z in (edge(xyz, goals, mask), edge.prefix(xyz, goals, mask, 12)):
        p = np.asarray(jax.nn.softmax(z))
        assert np.isfinite(p).all() and abs(p[mask].sum() - 1) < 1e-6 and (p[~mask] == 0).all()
