"""The zoo of people (slotv_jax.observers.zoo) against a float64 NumPy re-derivation of
experiments/zoo.md, formula by formula; its sampler against its probabilities; the
camera builder against a hand-made pose; --people's refusals."""

from __future__ import annotations

import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from slotv_jax.observers import zoo

RTOL = 2e-4  # float32 against float64 over 100 points of scans
ATOL = 2e-5


# ------------------------------------------------------------------ the reference


def np_look_at(pos, target, up):
    """The rotation of a camera at pos looking at target, written independently: the
    camera's −z points at the target, x is horizontal (⟂ up), y completes a right hand."""
    fwd = np.subtract(target, pos, dtype=np.float64)
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, up)
    right /= np.linalg.norm(right)
    cam_up = np.cross(right, fwd)
    return np.stack([right, cam_up, -fwd], axis=1)


def np_view(view, pts):
    if view == "table":
        return pts[:, :2]
    pos, target, _ = zoo.ZOO_CAMERAS[view]
    up = (1.0, 0.0, 0.0) if view == "zoo_overhead" else (0.0, 0.0, 1.0)
    R = np_look_at(pos, target, up)
    pc = (pts - np.asarray(pos)) @ R
    return pc[:, :2] / (-pc[:, 2:3])


def np_softmax(s, mask):
    s = np.where(mask, s, -np.inf)
    e = np.exp(s - s.max())
    return e / e.sum()


def np_reading(name, q, h, mask, L, u, p, world):
    n_goals = h.shape[0]
    d = np.linalg.norm(q[:, None, :] - h[None, :, :], axis=-1)  # (T, G)
    b = p["beta"]
    if name == "inverse_planning":
        post = u.copy()
        for i in range(1, L):
            post = ((1 - p["gamma"]) * post + p["gamma"] * u) * np.exp(b * (d[i - 1] - d[i]))
            post = np.where(mask, post, 0.0)
            post /= post.sum()
        return post
    if name == "extrapolation":
        v = np.zeros(2)
        for i in range(1, L):
            v = (1 - 1 / p["kappa"]) * v + (q[i] - q[i - 1]) / p["kappa"]
        ahead = q[L - 1] + p["horizon"] * v
        return np_softmax(-b * np.linalg.norm(ahead - h, axis=-1), mask)
    if name == "accumulator":
        a = np.zeros(n_goals)
        eps2 = zoo.DIRECTION_EPS**2
        for i in range(1, L):
            step, to = q[i] - q[i - 1], h - q[i]
            cos = (to @ step) / (np.sqrt(step @ step + eps2) * np.sqrt((to * to).sum(-1) + eps2))
            a = (1 - p["leak"]) * a + cos
        n_eff = sum((1 - p["leak"]) ** j for j in range(max(L - 1, 1)))
        return np_softmax(b * a / n_eff, mask)
    if name == "descent":
        z = world[:L, 2]
        w = 1 / (1 + np.exp(-(p["z_ref"] - z) / zoo.DESCENT_SCALE))
        s = (w[:, None] * -d[:L]).sum(0) / (w.sum() + zoo.DESCENT_DELTA)
        return np_softmax(b * s, mask)
    if name == "salience":
        prior = -p["centre_bias"] * np.linalg.norm(h, axis=-1)
        return np_softmax(prior + b * (d[0] - d[L - 1]), mask)
    if name == "anchor":
        T = q.shape[0]
        t = np.arange(T) / (T - 1)
        anchor_pts = [i for i in range(L) if t[i] <= p["anchor"]]
        i_a = np.floor(p["anchor"] * (T - 1))
        y = u.copy()
        if anchor_pts:
            y = np.mean([np_softmax(-b * d[i], mask) for i in anchor_pts], axis=0)
        for i in range(L):
            if t[i] > p["anchor"]:
                eta = p["eta0"] / (1 + i - i_a)
                y = y + eta * (np_softmax(b * (d[0] - d[i]), mask) - y)
        return y
    if name == "hesitant":
        y = np.zeros(n_goals)
        r = ((np.arange(L) + 1) / L) ** 2
        r /= r.sum()
        for i in range(L):
            bel = np_softmax(b * (d[0] - d[i]), mask)
            c = 1 / (1 + np.exp(-(bel.max() - p["threshold"]) / zoo.HESITANT_SHARPNESS))
            y += r[i] * (c * bel + (1 - c) * u)
        return y
    raise AssertionError(name)


def np_person(member, p, xyz, goals, mask, L):
    q, h = np_view(member.view, xyz), np_view(member.view, goals)
    u = mask / mask.sum()
    y = np_reading(member.name, q, h, mask, L, u, p, xyz)
    return np.where(mask, (1 - p["lapse"]) * y + p["lapse"] * u, 0.0)


# ------------------------------------------------------------------ cases


def scene_and_path(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 7))
    goals = np.zeros((8, 3))
    goals[:n, 0] = rng.uniform(0.3, 0.7, n)
    goals[:n, 1] = rng.uniform(-0.45, 0.45, n)
    goals[:n, 2] = 0.025
    mask = np.arange(8) < n
    via = rng.uniform([0.25, -0.5, 0.1], [0.7, 0.5, 0.4])
    start = np.array([0.3069, 0.0, 0.4869])
    t = np.linspace(0, 1, 100)[:, None]
    first = start + (via - start) * np.minimum(2 * t, 1)
    xyz = first + (goals[0] - via) * np.maximum(2 * t - 1, 0)
    return xyz, goals, mask


@pytest.mark.parametrize("name", zoo.zoo_names())
def test_each_member_is_its_formula(name):
    """Each member's person against the float64 re-derivation of experiments/zoo.md, for
    three drawn people, two scenes and three stop points (including the whole motion)."""
    member = zoo.MEMBERS[name]
    people = zoo.draw_people(member, jax.random.key(3), 3)
    for seed in (0, 1):
        xyz, goals, mask = scene_and_path(seed)
        for L in (7, 45, 100):
            for j in range(3):
                person = {k: v[j] for k, v in people.items()}
                got = zoo.person_probs(member, person, xyz, goals, mask, L)
                ref = np_person(member, {k: float(v) for k, v in person.items()}, xyz, goals,
                                mask, L)  # fmt: skip
                np.testing.assert_allclose(np.asarray(got), ref, rtol=RTOL, atol=ATOL)


@pytest.mark.parametrize("name", zoo.zoo_names())
def test_zoo_probs_is_a_distribution_with_finite_gradients(name):
    member = zoo.MEMBERS[name]
    xyz, goals, mask = scene_and_path(2)
    p = zoo.zoo_probs(member, xyz, goals, mask, 60)
    assert np.all(np.asarray(p)[~mask] == 0)
    assert abs(float(p.sum()) - 1) < 1e-5
    grad = jax.grad(lambda x: member.prefix(x, goals, mask, 60)[0])(jnp.asarray(xyz, jnp.float32))
    assert np.all(np.isfinite(np.asarray(grad)))
    # the observer's whole motion is its prefix at T
    np.testing.assert_allclose(
        member(xyz, goals, mask)[: mask.sum()], member.prefix(xyz, goals, mask, 100)[: mask.sum()]
    )
    # slots are exchangeable: permuting the real goals permutes the probabilities
    n = int(mask.sum())
    perm = np.r_[np.arange(n)[::-1], np.arange(n, 8)]
    p_perm = zoo.zoo_probs(member, xyz, goals[perm], mask[perm], 60)
    np.testing.assert_allclose(np.asarray(p_perm), np.asarray(p)[perm], atol=1e-6)


def test_the_sampler_draws_what_its_people_give():
    """The frequencies of 4,000 sampled guesses against the mean distribution of the same
    4,000 people (drawn with the sampler's own key half): within 4 standard errors."""
    member = zoo.MEMBERS["inverse_planning"]
    xyz, goals, mask = scene_and_path(4)
    key = jax.random.key(11)
    n = 4000
    guesses = np.asarray(zoo.sample_zoo_guesses(member, key, xyz, goals, mask, 40, n))
    people = zoo.draw_people(member, jax.random.split(key)[0], n)
    p = np.asarray(
        jax.vmap(lambda q: zoo.person_probs(member, q, xyz, goals, mask, 40))(people)
    ).mean(0)
    freq = np.bincount(guesses, minlength=8) / n
    se = np.sqrt(p * (1 - p) / n) + 1e-9
    assert np.all(np.abs(freq - p) <= 4 * se + 1e-12), (freq, p)
    assert np.all(freq[~mask] == 0)


def test_look_at_camera_matches_a_hand_made_pose():
    """A camera at (2, 0, 0) looking at the origin, z up, by hand: it looks along −x, so
    its z axis is +x̂; a viewer facing −x with z up has +ŷ on their right (its x axis) and
    +ẑ above (its y axis). Columns (x, y, z) = (ŷ, ẑ, x̂)."""
    cam = zoo.look_at_camera((2.0, 0.0, 0.0), (0.0, 0.0, 0.0), 40.0)
    np.testing.assert_allclose(np.asarray(cam.rot), [[0, 0, 1], [1, 0, 0], [0, 1, 0]], atol=1e-7)
    with pytest.raises(ValueError, match="fovy"):
        zoo.look_at_camera((2.0, 0.0, 0.0), (0.0, 0.0, 0.0), 180.0)
    with pytest.raises(ValueError, match="distinct"):
        zoo.look_at_camera((1.0, 0.0, 0.0), (1.0, 0.0, 0.0), 40.0)


def test_every_zoo_camera_sees_the_workspace():
    """Every corner of the via box and of the goal table lies in front of each zoo camera
    and inside its image (vertical field of view, 16:9)."""
    corners = np.array([[x, y, z] for x in (0.25, 0.7) for y in (-0.5, 0.5) for z in (0, 0.4)])
    for name, (_, _, fovy) in zoo.ZOO_CAMERAS.items():
        uv = np_view(name, corners)
        t = np.tan(np.radians(fovy) / 2)
        assert np.all(np.abs(uv[:, 1]) < t) and np.all(np.abs(uv[:, 0]) < t * 16 / 9), name


def test_load_people_refuses_what_is_not_people(tmp_path, monkeypatch):
    assert zoo.load_people("descent") is zoo.MEMBERS["descent"]
    (tmp_path / "my_people.py").write_text(
        textwrap.dedent(
            """
            import jax.numpy as jnp
            from slotv_jax.observers import zoo

            def good():
                return zoo.ZooMember("mine", "table", 10.0, (), lambda q, h, m, L, u, p, w:
                                     jnp.where(m, 1.0, 0.0) / jnp.sum(m), "mine")

            def bad_shape():
                return zoo.ZooMember("bad", "table", 10.0, (), lambda q, h, m, L, u, p, w:
                                     jnp.ones(3) / 3, "bad")

            def not_a_member():
                return 3
            """
        )
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    assert zoo.load_people("my_people:good").name == "mine"
    for spec, match in [
        ("nosuch", "expected a zoo member"),
        ("no_such_module_xyz:f", "cannot import module"),
        ("my_people:missing", "no function"),
        ("my_people:bad_shape", "finite \\(8,\\) distribution|fails on a test motion"),
        ("my_people:not_a_member", "must give a ZooMember"),
    ]:
        with pytest.raises(ValueError, match=match):
            zoo.load_people(spec)
    sys.modules.pop("my_people", None)
