"""The learned observers: SLOT-V's value network and T-REX's reward network (:ref:`concepts-slotv`,
:ref:`concepts-trex`).

Both methods share one network archetype, a function of one trajectory point
``r`` and one goal ``g`` through the goal-relative input ``r − g``:

    f(r, g) = w_L · σ(W_{L−1} ⋯ σ(W_1 (r − g) + b_1) ⋯),

with hidden widths ``hidden`` (paper: 1536/768 for SLOT-V, 1792/768 for T-REX) and the
activation σ: ReLU in the paper (the default), or softplus, σ(x) = log(1 + eˣ)
(``activation="softplus"``). A ReLU network is piecewise linear in r, so its gradient
∇_r f, which a planner follows, is piecewise constant and, away from the training
trajectories, arbitrary; a softplus network is smooth (experiments/planning_paper.md
measures what this does to legible planning).
For a trajectory p_0..p_{T−1} and goals g_1..g_8:

- SLOT-V's observer score is the mean over time, s_k = (1/T) Σ_i V(p_i, g_k),
  the integral of V over t ∈ [0, 1] (Wallkötter et al. 2022, §III);
- T-REX's return is the sum, R_k = Σ_i r(p_i, g_k) (Brown et al. 2019);
- both are computed as w_L · (reduction over i of the last hidden activation): the
  readout is linear, so it is applied once per goal instead of once per point;
- padded goal slots get the logit −∞, so softmax gives them probability 0 and
  the real goals' probabilities do not depend on the padding.

Because the first layer sees only r − g, translating a scene together with its
trajectory leaves every score unchanged. It is evaluated elementwise from r − g
(three products and a bias per element, fused by XLA into the kernel that consumes
them), never as a (T·G, 3) × (3, H) product. This layer is always in the parameters'
precision, float32 (r and g are metres of similar size, so rounding them before
the subtraction would cost accuracy near the goal); the hidden layers use
``compute_dtype`` (bfloat16 on GPUs) with float32 parameters, and the scalar
output and the reduction over time are float32.

>>> import jax, jax.numpy as jnp
>>> from flax import nnx
>>> m = SlotV((16, 8), rngs=nnx.Rngs(0))
>>> xyz = jnp.linspace(0.0, 0.3, 300).reshape(100, 3)
>>> goals = jnp.zeros((8, 3)).at[1, 0].set(0.5)
>>> m(xyz, goals, jnp.arange(8) < 2).shape
(8,)
"""

from __future__ import annotations

import functools
import itertools
import math
from collections.abc import Sequence

import jax
import jax.numpy as jnp
from flax import nnx
from jaxtyping import Array, Bool, Float, Int

from slotv_jax.observers import archetypes, common, parametric, reader
from slotv_jax.observers.common import mask_logits as mask_logits

# the observer type, its protocol and its input checks (their home: observers/observer.py)
from slotv_jax.observers.observer import Observer as Observer
from slotv_jax.observers.observer import ObserverLike as ObserverLike
from slotv_jax.observers.observer import check_observer_inputs as check_observer_inputs
from slotv_jax.observers.observer import check_seen as check_seen

_DTYPES = {"float32": jnp.float32, "bfloat16": jnp.bfloat16}
BACKWARDS = ("autodiff", "fused", "recompute")  # see GoalRelativeMLP.grid
# activation name -> (σ, δ(pre, dh) = σ'(pre) ⊙ dh, in the cotangent's dtype: what the
# custom backward passes of the first layers compute)
ACTIVATIONS = {
    "relu": (jax.nn.relu, lambda pre, dh: jnp.where(pre > 0, dh, jnp.zeros((), dh.dtype))),
    "softplus": (jax.nn.softplus, lambda pre, dh: dh * jax.nn.sigmoid(pre).astype(dh.dtype)),
}
_List = getattr(nnx, "List", list)  # flax < 0.12 keeps sub-modules in plain lists
ALPHA_INIT = 1.0  # initial time-weighting exponent: Dragan & Srinivasa's f(t) = T − t


def _dtype(name: str):
    if name not in _DTYPES:
        raise ValueError(f"compute_dtype: expected one of {tuple(_DTYPES)}, got {name!r}")
    return _DTYPES[name]


def _activation(name: str):
    if name not in ACTIVATIONS:
        raise ValueError(f"activation: expected one of {tuple(ACTIVATIONS)}, got {name!r}")
    return ACTIVATIONS[name][0]


class GoalRelativeMLP(nnx.Module):
    """f(r, g) = MLP(r − g): Dense(hidden[0]) σ → … → Dense(hidden[-1]) σ → Dense(1), with σ
    the ``activation`` (:data:`ACTIVATIONS`: "relu", the paper's, or "softplus").

    The output layer has no bias: softmax over goals (SLOT-V) and the pairwise loss
    (T-REX) are both invariant to it.

    Parameters are float32; the hidden matmuls run in ``compute_dtype``.
    """

    def __init__(
        self,
        hidden: Sequence[int],
        *,
        activation: str = "relu",
        compute_dtype: str = "float32",
        rngs: nnx.Rngs,
    ):
        hidden = tuple(int(h) for h in hidden)
        if not hidden or min(hidden) < 1:
            raise ValueError(f"hidden: expected positive widths, got {hidden}")
        # float32 compute: no explicit dtype, so float64 parameters (under jax x64) give a
        # float64 model, e.g. for finite-difference checks.
        cd = None if compute_dtype == "float32" else _dtype(compute_dtype)
        out = None if cd is None else jnp.float32
        _activation(activation)
        self.hidden = hidden
        self.activation = activation
        self.compute_dtype = compute_dtype
        self.first = nnx.Linear(3, hidden[0], precision=jax.lax.Precision.HIGHEST, rngs=rngs)
        self.layers = _List(
            [nnx.Linear(a, b, dtype=cd, rngs=rngs) for a, b in itertools.pairwise(hidden)]
        )
        # No output bias [choice]: a constant added to f shifts every goal's score equally,
        # which neither the softmax over goals nor T-REX's pairwise loss can see. Its
        # gradient is zero up to rounding, and RMSprop/Adam would blow that noise up into
        # steps of size ~lr (a random walk that makes runs irreproducible across devices).
        self.readout = nnx.Linear(
            hidden[-1], 1, use_bias=False, dtype=cd, preferred_element_type=out, rngs=rngs
        )

    def _hidden(self, h: Array, start: int = 0) -> Array:
        """Hidden layers ``start``… from the activations before them (in ``compute_dtype``)."""
        if self.compute_dtype != "float32":
            h = h.astype(_dtype(self.compute_dtype))
        act = _activation(self.activation)
        for layer in self.layers[start:]:
            h = act(layer(h))
        return h

    def _readout(self, h: Array, out) -> Array:
        """The scalar output from the last hidden activation, as ``out`` (≥ float32)."""
        return self.readout(h)[..., 0].astype(jnp.promote_types(out, jnp.float32))

    def __call__(self, r: Float[Array, "... 3"], g: Float[Array, "... 3"]) -> Float[Array, "..."]:
        """f(r, g) for broadcastable batches of points and goals."""
        h = _activation(self.activation)(self.first(r - g))
        return self._readout(self._hidden(h), h.dtype)

    def grid(
        self,
        xyz: Float[Array, "... T 3"],
        goals: Float[Array, "... G 3"],
        *,
        backward: str = "autodiff",
    ) -> Float[Array, "... T G"]:
        """f(p_i, g_k) for every point and goal: W_1 (p_i − g_k) + b_1, then the trunk.

        ``backward`` picks how the gradient of the first layers is computed (the values are
        the same): "autodiff" (plain JAX; supports every transformation), or, for training
        (reverse mode only), "fused" (:func:`goal_relative_features` with its one-pass
        custom gradient) or "recompute" (:func:`goal_relative_two_layers`: the first
        activation is recomputed in the backward pass instead of stored).
        """
        return self._readout(self._last_hidden(xyz, goals, backward), self.first.kernel.dtype)

    def integrate(
        self,
        xyz: Float[Array, "... T 3"],
        goals: Float[Array, "... G 3"],
        *,
        reduce: str = "mean",
        weights: Float[Array, " T"] | None = None,
        from_start: bool = False,
        backward: str = "autodiff",
    ) -> Float[Array, "... G"]:
        """``grid(xyz, goals)`` reduced over the points (``reduce``: "mean" or "sum"), each
        point's value times ``weights[i]`` if given (weights of mean 1 keep the scale) and,
        with ``from_start``, taken relative to the first point's: f(p_i, g) − f(p_0, g).

        The readout is linear, so the reduction is taken first, on the last hidden
        activation (accumulated in float32), and the readout is applied once per goal
        in float32: mean_i w · h(p_i, g_k) = w · mean_i h(p_i, g_k). The same values as
        reducing :meth:`grid` (up to rounding), without a (T·G, H) product with w and
        its transposes in the backward pass.
        """
        if reduce not in ("mean", "sum"):
            raise ValueError(f"reduce: expected 'mean' or 'sum', got {reduce!r}")
        h = self._last_hidden(xyz, goals, backward)  # (..., T, G, H)
        acc = jnp.promote_types(self.readout.kernel.dtype, jnp.float32)
        if weights is None:
            pooled = jnp.sum(h, axis=-3, dtype=acc)  # Σ_t, accumulated in float32
        else:  # Σ_t w_t h_t, accumulated in float32
            w = weights.astype(h.dtype)
            pooled = jnp.einsum("...tgh,t->...gh", h, w, preferred_element_type=acc)
        if from_start:  # Σ_t w_t (h_t − h_0): the total weight times the first point's
            total = h.shape[-3] if weights is None else jnp.sum(weights, dtype=acc)
            pooled = pooled - total * h[..., 0, :, :].astype(acc)
        if reduce == "mean":
            pooled = pooled / h.shape[-3]
        w = self.readout.kernel[...][:, 0].astype(acc)
        return jnp.matmul(pooled, w, precision=jax.lax.Precision.HIGHEST)

    def _last_hidden(self, xyz, goals, backward: str) -> Array:
        """The last hidden activation for every (point, goal): (..., T, G, H_last)."""
        cd = None if self.compute_dtype == "float32" else _dtype(self.compute_dtype)
        w1, b1 = self.first.kernel[...], self.first.bias[...]
        if backward == "recompute" and len(self.layers) > 0:
            l2 = self.layers[0]
            w2, b2 = l2.kernel[...], l2.bias[...]
            z2 = goal_relative_two_layers(xyz, goals, w1, b1, w2, b2, cd, self.activation)
            return self._hidden(_activation(self.activation)(z2), start=1)
        if backward not in BACKWARDS:
            raise ValueError(f"backward: expected one of {BACKWARDS}, got {backward!r}")
        fused = backward == "fused"
        h = goal_relative_features(xyz, goals, w1, b1, cd, fused, activation=self.activation)
        return self._hidden(h)


def _pre_activation(xyz, goals, w, b):
    """W_1 (p_t − g_k) + b_1 for every (t, k): (..., T, G, H), in the parameters' precision.

    d = p_t − g_k first (exact when p_t is near g_k), then the three-term product written
    out elementwise: XLA fuses the whole layer into the kernel that consumes it, so the
    only (T·G, H) memory traffic is that kernel's output.
    """
    d = xyz[..., :, None, :] - goals[..., None, :, :]  # (..., T, G, 3)
    return d[..., 0:1] * w[0] + d[..., 1:2] * w[1] + d[..., 2:3] * w[2] + b


def _features(xyz, goals, w, b, dtype, activation):
    h = _activation(activation)(_pre_activation(xyz, goals, w, b))
    return h if dtype is None else h.astype(dtype)


@functools.partial(jax.custom_vjp, nondiff_argnums=(4, 5))
def _features_fused(xyz, goals, w, b, dtype, activation):
    return _features(xyz, goals, w, b, dtype, activation)


def _features_fused_fwd(xyz, goals, w, b, dtype, activation):
    return _features(xyz, goals, w, b, dtype, activation), (xyz, goals, w, b)


def _features_fused_bwd(dtype, activation, res, dh):
    xyz, goals, w, b = res
    hp = jax.lax.Precision.HIGHEST
    pre = _pre_activation(xyz, goals, w, b)  # (..., T, G, H), recomputed, never stored
    dpre = ACTIVATIONS[activation][1](pre, dh)
    f32 = jnp.promote_types(dpre.dtype, jnp.float32)
    # W_1 and b_1 as one skinny matmul over all (t, k) rows: Σ_{t,k} (p_t − g_k, 1) ⊗ δ_tk
    d = xyz[..., :, None, :] - goals[..., None, :, :]  # (..., T, G, 3)
    d4 = jnp.concatenate([d, jnp.ones_like(d[..., :1])], axis=-1).astype(dpre.dtype)
    rows = tuple(range(dpre.ndim - 1))
    dwb = jax.lax.dot_general(d4, dpre, ((rows, rows), ((), ())), preferred_element_type=f32)
    # the inputs (dead code, removed by XLA, when only parameters are differentiated)
    dxyz = jnp.matmul(dpre.sum(-2, dtype=f32), w.T, precision=hp)
    dgoals = -jnp.matmul(dpre.sum(-3, dtype=f32), w.T, precision=hp)
    return (
        dxyz.astype(xyz.dtype),
        dgoals.astype(goals.dtype),
        dwb[:3].astype(w.dtype),
        dwb[3].astype(b.dtype),
    )


_features_fused.defvjp(_features_fused_fwd, _features_fused_bwd)


def _two_layers(xyz, goals, w1, b1, w2, b2, dtype, activation):
    h1 = _features(xyz, goals, w1, b1, dtype, activation)
    return jnp.matmul(h1, w2.astype(h1.dtype)) + b2.astype(h1.dtype)


@functools.partial(jax.custom_vjp, nondiff_argnums=(6, 7))
def _two_layers_recompute(xyz, goals, w1, b1, w2, b2, dtype, activation):
    return _two_layers(xyz, goals, w1, b1, w2, b2, dtype, activation)


def _two_layers_fwd(xyz, goals, w1, b1, w2, b2, dtype, activation):
    out = _two_layers(xyz, goals, w1, b1, w2, b2, dtype, activation)
    return out, (xyz, goals, w1, b1, w2, b2)


def _two_layers_bwd(dtype, activation, res, dz):
    xyz, goals, w1, b1, w2, b2 = res
    h1 = _features(xyz, goals, w1, b1, dtype, activation)  # recomputed, not stored
    rows = tuple(range(h1.ndim - 1))
    f32 = jnp.promote_types(w2.dtype, jnp.float32)  # float32 (float64 under x64)
    dw2 = jax.lax.dot_general(h1, dz, ((rows, rows), ((), ())), preferred_element_type=f32)
    db2 = jnp.sum(dz.astype(f32), axis=rows)
    dh1 = jnp.matmul(dz, w2.astype(h1.dtype).T)
    dxyz, dgoals, dw1, db1 = _features_fused_bwd(dtype, activation, (xyz, goals, w1, b1), dh1)
    return dxyz, dgoals, dw1, db1, dw2.astype(w2.dtype), db2.astype(b2.dtype)


_two_layers_recompute.defvjp(_two_layers_fwd, _two_layers_bwd)


def goal_relative_two_layers(
    xyz: Float[Array, "... T 3"],
    goals: Float[Array, "... G 3"],
    w1: Float[Array, "3 H"],
    b1: Float[Array, " H"],
    w2: Float[Array, "H N"],
    b2: Float[Array, " N"],
    dtype=None,
    activation: str = "relu",
) -> Float[Array, "... T G N"]:
    """Pre-activation of the second hidden layer, W_2 σ(W_1 (p_t − g_k) + b_1) + b_2, with
    a custom gradient that recomputes the first activation in the backward pass (so the
    forward pass stores only its small inputs) and reuses the one-pass first-layer gradient
    of :func:`goal_relative_features`. Matmuls in ``dtype`` (None: the parameters' dtype),
    weight gradients accumulated in float32; σ the ``activation`` (:data:`ACTIVATIONS`).
    Reverse mode only."""
    _activation(activation)
    return _two_layers_recompute(xyz, goals, w1, b1, w2, b2, dtype, activation)


def goal_relative_features(
    xyz: Float[Array, "... T 3"],
    goals: Float[Array, "... G 3"],
    w: Float[Array, "3 H"],
    b: Float[Array, " H"],
    dtype=None,
    fused_backward: bool = False,
    *,
    activation: str = "relu",
) -> Float[Array, "... T G H"]:
    """First hidden layer on every (point, goal) pair: σ(W_1 (p_t − g_k) + b_1), in the
    parameters' precision (float32), then cast to ``dtype`` (None: keep); σ the
    ``activation`` (:data:`ACTIVATIONS`).

    With ``fused_backward`` the gradient is a custom VJP that recomputes the
    pre-activation instead of storing a mask, and gets ∂L/∂W_1 = Σ_{t,k} (p_t − g_k) ⊗ δ_{tk}
    and ∂L/∂b_1 = Σ_{t,k} δ_{tk} as one (4 × T·G) · (T·G × H) matmul over
    δ = ∂L/∂pre = σ'(pre) ⊙ ∂L/∂h (accumulated in float32), instead of reductions over k
    and over t followed by small products (autodiff): the (T·G, H) tensors dominate the
    memory traffic of a training step. Reverse mode only (no ``jvp``); the default path
    supports both.
    """
    _activation(activation)
    if fused_backward:
        return _features_fused(xyz, goals, w, b, dtype, activation)
    return _features(xyz, goals, w, b, dtype, activation)


class _ScoreNetwork(nnx.Module):
    """Per-goal scores of a trajectory (``scores``, set by the subclass); ``__call__`` masks
    the padded goals to −∞.

    With ``time_weight`` the points are weighted by (1 − t_i)^α (normalised to mean 1) with
    a learned α ≥ 0, the weighting of Dragan & Srinivasa's legibility integral (f(t) = T − t
    at α = 1): an observer that judges the motion by what it shows early. α starts at
    :data:`ALPHA_INIT` = 1 (measured on the quick data: from 1, planning kept 94 % of the
    oracle's gain; from 0.05, near the paper's plain mean, 88 % after the same updates).

    With ``start_term`` every point's value is taken relative to the trajectory's first
    point, f(p_i, g_k) − f(p_0, g_k): SLOT-V's score becomes the (weighted) mean value
    gained since the start. The observers of Dragan (:ref:`concepts-dragan`) and FastApp (§4.4,
    after summation by parts) score the progress made since the start, ‖S − g_k‖ − d_k(i); a
    function of p − g alone cannot hold the per-goal constant ‖S − g_k‖, except through
    its values at the offsets where the training trajectories start, and a planner that
    moves the first waypoints exploits exactly those. (A learned weight w₀ of the start's
    value, tried first, settled near −1 on the quick data but drifted to +1.2–1.7 at the
    paper's size, where planning kept less of the oracle's gain: experiments/
    planning_paper.md.)
    """

    reduce: str  # over the points: "mean" (SLOT-V) or "sum" (T-REX)
    network_name: str  # the attribute holding the GoalRelativeMLP ("value", "reward")
    default_hidden: tuple[int, ...]  # the paper's widths

    def __init__(
        self,
        hidden: Sequence[int] | None = None,
        *,
        activation: str = "relu",
        start_term: bool = False,
        time_weight: bool = False,
        compute_dtype: str = "float32",
        rngs: nnx.Rngs,
    ):
        hidden = self.default_hidden if hidden is None else hidden
        net = GoalRelativeMLP(hidden, activation=activation, compute_dtype=compute_dtype, rngs=rngs)
        setattr(self, self.network_name, net)
        self.start_term = bool(start_term)
        raw = math.log(math.expm1(ALPHA_INIT))  # softplus⁻¹
        self.raw_alpha = nnx.Param(jnp.asarray(raw, jnp.float32)) if time_weight else None

    @property
    def network(self) -> GoalRelativeMLP:
        """The network f: SLOT-V's value V, T-REX's reward r."""
        return getattr(self, self.network_name)

    @property
    def alpha(self) -> Float[Array, ""] | None:
        """The learned time-weighting exponent α = softplus(raw) ≥ 0 (None without one)."""
        return None if self.raw_alpha is None else jax.nn.softplus(self.raw_alpha[...])

    def point_weights(self, n_points: int) -> Float[Array, " T"] | None:
        """Per-point weights of mean 1, u_i · T with u the normalised (1 − t_i)^α
        (:func:`slotv_jax.observers.parametric.time_weights`), or None (every point counts the
        same)."""
        if self.raw_alpha is None:
            return None
        a = self.alpha
        return n_points * parametric.time_weights(a, n_points, a.dtype)

    def scores(
        self, xyz: Float[Array, "... T 3"], goals: Float[Array, "... G 3"], **kw
    ) -> Float[Array, "... G"]:
        """Unmasked scores: f integrated over the points (the class docstring's equation)."""
        return self.network.integrate(
            xyz,
            goals,
            reduce=self.reduce,
            weights=self.point_weights(xyz.shape[-2]),
            from_start=self.start_term,
            **kw,
        )

    def __call__(
        self,
        xyz: Float[Array, "... T 3"],
        goals: Float[Array, "... G 3"],
        goal_mask: Bool[Array, "... G"],
    ) -> Float[Array, "... G"]:
        """Masked scores, the logits of softmax over real goals (SLOT-V: P(goal k |
        trajectory); T-REX: the evaluation logits of :ref:`concepts-trex`)."""
        return mask_logits(self.scores(xyz, goals), goal_mask)

    def prefix_scores(
        self,
        xyz: Float[Array, "... T 3"],
        goals: Float[Array, "... G 3"],
        goal_mask: Bool[Array, "... G"] | None,
        seen: Int[Array, "..."],
        *,
        backward: str = "autodiff",
    ) -> Float[Array, "... G"]:
        """Unmasked scores of the first ``seen`` = L points of each trajectory (L traced;
        ``goal_mask`` is not needed), what training on answers optimises::

            SLOT-V: s_k = (1/L) Σ_{i<L} V(p_i, g_k);   T-REX: s_k = Σ_{i<L} r(p_i, g_k)

        With time weights u_i the seen points are weighted by them (SLOT-V's s_k is then
        Σ_{i<L} u_i V(p_i, g_k) / Σ_{i<L} u_i, T-REX's Σ_{i<L} u_i r(p_i, g_k); u at the
        whole motion's times); with the start term every value is taken relative to
        f(p_0, g_k) (p_0 is always seen). Points i ≥ L are replaced by p_0 before the
        network and weighted 0, so their values reach neither the scores nor any gradient.
        With L = T this is :meth:`scores` (up to summation order).
        """
        t = xyz.shape[-2]
        vis = jnp.arange(t) < jnp.asarray(seen)[..., None]  # (..., T)
        v = self.network.grid(common.seen_only(xyz, seen), goals, backward=backward)  # (.., T, G)
        if self.start_term:  # values relative to the start's (point 0 is always seen)
            v = v - v[..., :1, :]
        w = vis.astype(v.dtype)
        u = self.point_weights(t)  # time weights of mean 1 over the whole trajectory, or None
        if u is not None:
            w = w * u.astype(v.dtype)
        if self.method == "slotv":
            w = w / w.sum(-1, keepdims=True)
        return jnp.einsum("...tg,...t->...g", v, w, precision=jax.lax.Precision.HIGHEST)

    def prefix(
        self,
        xyz: Float[Array, "... T 3"],
        goals: Float[Array, "... G 3"],
        goal_mask: Bool[Array, "... G"],
        seen: Int[Array, "..."],
    ) -> Float[Array, "... G"]:
        """The logits of the motion seen up to its first ``seen`` points: masked
        :meth:`prefix_scores`."""
        return mask_logits(self.prefix_scores(xyz, goals, goal_mask, seen), goal_mask)


class SlotV(_ScoreNetwork):
    """SLOT-V observer: logits s_k = (1/T) Σ_i V(p_i, g_k) (:ref:`concepts-slotv`), padded goals at
    −∞; the options give s_k = (1/T) Σ_i u_i [V(p_i, g_k) − V(p_0, g_k)] (:class:`_ScoreNetwork`).
    ``hidden`` defaults to the paper's (1536, 768)."""

    method = "slotv"
    reduce = "mean"
    network_name = "value"
    default_hidden = (1536, 768)


class TRex(_ScoreNetwork):
    """Adapted T-REX: per-goal returns R_k = Σ_i r(p_i, g_k) (:ref:`concepts-trex`), padded goals at
    −∞; the options give R_k = Σ_i u_i [r(p_i, g_k) − r(p_0, g_k)] (:class:`_ScoreNetwork`).
    ``hidden`` defaults to the paper's (1792, 768)."""

    method = "trex"
    reduce = "sum"
    network_name = "reward"
    default_hidden = (1792, 768)


Model = SlotV | TRex | reader.MotionReader


def make_model(cfg, rngs: nnx.Rngs | jax.Array | int) -> Model:
    """Build the model a :class:`slotv_jax.training.config.TrainConfig` describes: its ``model``
    archetype of :mod:`slotv_jax.observers.parametric` (deterministic, ``rngs`` unused), the
    motion reader (``model="reader"``, :mod:`slotv_jax.observers.reader`: its ``hidden``,
    ``activation`` and ``camera``), or for the MLP (``model="mlp"``) SLOT-V's or T-REX's
    network."""
    model = getattr(cfg, "model", "mlp")
    if not isinstance(rngs, nnx.Rngs):
        rngs = nnx.Rngs(rngs)
    if model == "reader":
        return reader.MotionReader(
            cfg.hidden, activation=cfg.activation, camera=cfg.camera, rngs=rngs
        )
    if model != "mlp":
        return archetypes.make_archetype(model)
    cls = {"slotv": SlotV, "trex": TRex}.get(cfg.method)
    if cls is None:
        raise ValueError(f"cfg.method: expected 'slotv' or 'trex', got {cfg.method!r}")
    return cls(
        cfg.hidden,
        activation=getattr(cfg, "activation", "relu"),
        start_term=getattr(cfg, "start_term", False),
        time_weight=getattr(cfg, "time_weight", False),
        compute_dtype=cfg.compute_dtype,
        rngs=rngs,
    )


@functools.cache
def graphdef(cfg) -> nnx.GraphDef:
    """The ``nnx`` graph definition of :func:`make_model`'s model for ``cfg`` (no parameters
    are allocated): ``nnx.merge(graphdef(cfg), params)`` rebuilds the model."""
    return nnx.split(nnx.eval_shape(lambda: make_model(cfg, nnx.Rngs(0))))[0]


def sample_trex_pairs(
    key: jax.Array, goal_mask: Bool[Array, "N 8"], labels: Float[Array, "N 8"], n_pairs: int
) -> tuple[Array, Array, Array]:
    """T-REX training pairs exactly as :ref:`concepts-trex`, drawn on device.

    Two trajectories i₁, i₂ uniform over the N trajectories (independently, with
    replacement); for each, a goal slot k_j uniform over its scene's real goals (real
    goals fill the first slots); the label is ℓ = 1[y_{k₂}(i₂) > y_{k₁}(i₁)].

    Returns ``idx (n, 2)`` int32, ``slot (n, 2)`` int32 and ``label (n,)`` float32 in {0, 1}.
    """
    k_idx, k_goal = jax.random.split(key)
    idx = jax.random.randint(k_idx, (n_pairs, 2), 0, goal_mask.shape[0])
    n_real = goal_mask[idx].sum(-1)  # (n, 2)
    slot = jax.random.randint(k_goal, (n_pairs, 2), 0, n_real)
    y = labels[idx, slot]  # (n, 2)
    return idx, slot, (y[:, 1] > y[:, 0]).astype(jnp.float32)
