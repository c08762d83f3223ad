"""The shared observer maths (slotv_jax.observers.common, the projection of
slotv_jax.world.scene) against hand cases and the float64 reference labelers."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import ref_labelers as ref

from slotv_jax import labelers
from slotv_jax.observers import common
from slotv_jax.world import scene


def test_masks_by_hand():
    s = jnp.array([1.0, 3.0, 2.0, 50.0])
    mask = jnp.array([True, True, True, False])
    assert common.mask_logits(s, mask).tolist() == [1.0, 3.0, 2.0, -np.inf]
    e = np.exp([1.0, 3.0, 2.0])
    np.testing.assert_allclose(common.masked_softmax(s, mask), [*(e / e.sum()), 0.0], rtol=1e-6)
    assert float(common.masked_softmax(s, mask)[3]) == 0.0  # exactly
    y = jnp.array([0.25, 0.5, 0.25, 0.0])  # the padded slot holds an exact 0
    np.testing.assert_allclose(common.masked_log(y, mask)[:3], np.log(y[:3]), rtol=1e-6)
    assert float(common.masked_log(y, mask)[3]) == -np.inf
    g = jax.grad(lambda y: common.masked_log(y, mask)[0])(y)  # no 0/0 from the padded slot
    assert np.all(np.isfinite(np.asarray(g)))


def test_time_weights_by_hand_and_in_both_forms():
    tau = common.uniform_times(3)
    np.testing.assert_allclose(common.trapezoid(tau, np), [0.25, 0.5, 0.25])
    # :ref:`concepts-dragan`'s integration weights: trap · (1 − τ) = (0.25, 0.25, 0), normalised
    c = common.time_weights(tau, 1.0, trapezoid_rule=True)
    np.testing.assert_allclose(c, [0.5, 0.5, 0], rtol=1e-15, atol=1e-300)
    np.testing.assert_allclose(common.time_weights(tau, 0.0), [1 / 3] * 3)
    irregular = np.array([0.0, 0.1, 0.5, 0.6, 1.0])
    for alpha in (0.0, 0.5, 1.0, 2.0):
        for trap in (False, True):
            want = {}
            for dt in (np.float64, np.float32):  # 1 − τ floored at the dtype's tiny
                w = np.maximum(1.0 - irregular, np.finfo(dt).tiny) ** alpha
                w = w * (common.trapezoid(irregular, np) if trap else 1.0)
                want[dt] = w / w.sum()
            kw = {"trapezoid_rule": trap}
            lin = common.time_weights(irregular, alpha, **kw)  # float64, linear form
            np.testing.assert_allclose(lin, want[np.float64], rtol=1e-12)
            traced = common.time_weights(irregular, jnp.float32(alpha), **kw)  # softmax form
            np.testing.assert_allclose(traced, want[np.float32], rtol=2e-6, atol=1e-37)
            log_w = common.log_time_weights(jnp.asarray(irregular, jnp.float32), alpha, **kw)
            np.testing.assert_allclose(np.exp(log_w), want[np.float32], rtol=2e-6, atol=1e-37)


@pytest.mark.parametrize("beta", [5.0, 20.0, 400.0])
def test_dragan_kernel_equals_the_labeler_and_the_reference(beta):
    """The one Dragan kernel in both forms, log space (the archetypes) and linear (the
    labelers), against a float64 reference, up to a β far above the datasets'."""
    rng = np.random.default_rng(3)
    for n in (2, 5, 8):
        xyz = rng.uniform([0.25, -0.5, 0.1], [0.7, 0.5, 0.4], (40, 3))
        goals = np.zeros((8, 3))
        goals[:n, :2] = rng.uniform([0.3, -0.45], [0.7, 0.45], (n, 2))
        mask = np.arange(8) < n
        want = ref.dragan(xyz, goals, mask, beta=beta)
        log_y = common.dragan_log_labels(jnp.asarray(xyz, jnp.float32),
                                         jnp.asarray(goals, jnp.float32), mask, beta)  # fmt: skip
        y = np.exp(np.asarray(common.mask_logits(log_y, mask)))
        np.testing.assert_allclose(y, want, atol=1e-6)
        y_fused = labelers.dragan(xyz.astype(np.float32), goals, mask, beta=beta)
        np.testing.assert_allclose(y, np.asarray(y_fused), atol=1e-6)


def test_projection_by_hand_and_guarded():
    cam = scene.camera("observer")
    pos, rot = np.asarray(cam.pos, np.float64), np.asarray(cam.rot, np.float64)
    p = np.array([[0.45, 0.0, 0.15], [0.6, 0.2, 0.1]])
    pc = (p - pos) @ rot  # the SPEC's p_c = Rᵀ (p − c), as a matrix product
    np.testing.assert_allclose(np.stack(scene.camera_coords(p, pos, rot), -1), pc, atol=1e-12)
    uv, depth = scene.project(p, scene.Camera(pos=pos, rot=rot, fovy=cam.fovy,
                                              resolution=cam.resolution))  # fmt: skip
    assert isinstance(uv, np.ndarray) and uv.dtype == np.float64
    np.testing.assert_allclose(uv, pc[:, :2] / -pc[:, 2:], atol=1e-12)
    np.testing.assert_allclose(depth, -pc[:, 2], atol=1e-12)
    behind = pos + 0.5 * rot[:, 2]  # half a metre behind the camera (it looks along −z)
    pts = jnp.asarray(np.stack([p[0], behind]), jnp.float32)
    (u, v), ok = scene.image_coords(pts, cam.pos, cam.rot, 1e-6)
    assert ok.tolist() == [True, False]
    assert np.all(np.isfinite(np.asarray(u))) and np.all(np.isfinite(np.asarray(v)))
    g = jax.grad(lambda x: jnp.sum(scene.image_coords(x, cam.pos, cam.rot, 1e-6)[0][0]))(pts)
    assert np.all(np.isfinite(np.asarray(g)))
