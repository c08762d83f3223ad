"""The archetype registry and the distance/approach mixture: :data:`ARCHETYPES` names the three
parametric observers of :mod:`slotv_jax.observers.parametric` that ``TrainConfig.model``
selects, and :func:`archetype_observer`, an archetype as the library's
:class:`~slotv_jax.observers.observer.Observer`.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
from flax import nnx
from jaxtyping import Array, Float, Int

from slotv_jax.observers import common
from slotv_jax.observers.observer import Observer, check_observer_inputs, check_seen
from slotv_jax.observers.parametric import (
    LearnableDragan,
    LearnableViewpoint,
    _alpha_words,
    _Archetype,
    _check,
    _inv_softplus,
    _log,
    _param,
    _value,
    time_weights,
)

# ------------------------------------------------------------------ distance/approach mixture


class DistanceApproachMixture(_Archetype):
    """A learned combination of an EffDist-like and a FastApp-like observer
    (:ref:`concepts-effdist`, :ref:`concepts-fastapp`).

    With d_k(i) = ‖p_i − g_k‖ (m) at t_i = i/(T − 1)::

        E_k = −Σ_i u_i d_k(i),                        u_i ∝ (1 − t_i)^α_E,  Σ u = 1   (m)
        F_k = Σ_{i≥1} v_i (d_k(i−1) − d_k(i)) / Δt,   v_i ∝ (1 − t_i)^α_F,  Σ v = 1   (m)
        s_k = β_E E_k + β_F F_k

    E is minus the time-weighted mean distance to the goal, F the time-weighted mean
    approach speed (m per unit of normalised time, i.e. metres over the whole motion), so
    both temperatures are per metre and the EffDist share β_E / (β_E + β_F) says which
    term the observer follows. β_E = β, α_E = 0, β_F = 0 is ``labelers.effdist`` at β;
    β_E = 0, β_F = β, α_F = 1 is ``labelers.fastapp`` at β (as log-probabilities up to
    a constant per trajectory).

    Parameters: β_E, β_F ≥ 0 (``exp``; 0 at −∞), α_E, α_F ≥ 0 (``softplus``). Defaults:
    β_E = β_F = 5 (an even mix) and α_E = α_F = 1.

    >>> m = DistanceApproachMixture()
    >>> round(m.parameters()["effdist_share"], 2)
    0.5
    """

    name = "mixture"

    def __init__(
        self,
        *,
        beta_effdist: float = 5.0,
        beta_fastapp: float = 5.0,
        alpha_effdist: float = 1.0,
        alpha_fastapp: float = 1.0,
    ):
        _check("beta_effdist", beta_effdist, strict=False)
        _check("beta_fastapp", beta_fastapp, strict=False)
        if not beta_effdist + beta_fastapp > 0:
            raise ValueError("beta_effdist, beta_fastapp: expected at least one > 0")
        _check("alpha_effdist", alpha_effdist, strict=False)
        _check("alpha_fastapp", alpha_fastapp, strict=False)
        self.log_beta_effdist = _param(_log(beta_effdist))
        self.log_beta_fastapp = _param(_log(beta_fastapp))
        self.raw_alpha_effdist = _param(_inv_softplus(alpha_effdist))
        self.raw_alpha_fastapp = _param(_inv_softplus(alpha_fastapp))

    def _constrained(self) -> dict[str, Array]:
        return {
            "beta_effdist": jnp.exp(_value(self.log_beta_effdist)),
            "beta_fastapp": jnp.exp(_value(self.log_beta_fastapp)),
            "alpha_effdist": jax.nn.softplus(_value(self.raw_alpha_effdist)),
            "alpha_fastapp": jax.nn.softplus(_value(self.raw_alpha_fastapp)),
        }

    def terms(
        self,
        xyz: Float[Array, "... T 3"],
        goals: Float[Array, "... G 3"],
        seen: Int[Array, "..."] | None = None,
    ) -> tuple[Float[Array, "... G"], Float[Array, "... G"]]:
        """The two terms (E, F), in metres, before their temperatures; with ``seen`` = L
        (traced), those of ``xyz[..., :L, :]`` at its own times t_i = i/(L − 1)."""
        p = self._constrained()
        hp = jax.lax.Precision.HIGHEST
        if seen is None:
            d = common.pairwise_distances(xyz, goals)  # (..., T, G)
            T = d.shape[-2]
            u = time_weights(p["alpha_effdist"], T, d.dtype)
            v = common.time_weights(common.uniform_times(T)[1:], p["alpha_fastapp"], dtype=d.dtype)
            e = -jnp.einsum("...tg,t->...g", d, u, precision=hp)
            approach = d[..., :-1, :] - d[..., 1:, :]  # (..., T−1, G)
            f = jnp.einsum("...tg,t->...g", approach, v, precision=hp)
            return e, f * (T - 1)
        L = jnp.asarray(seen)
        d = common.pairwise_distances(common.seen_only(xyz, L), goals)  # (..., T, G)
        T = d.shape[-2]
        u = common.prefix_time_weights(T, L, p["alpha_effdist"], dtype=d.dtype)  # (..., T)
        tau = common.prefix_times(T, L, d.dtype)[..., 1:]  # t_1..t_{L−1}, then 1s
        valid = jnp.arange(1, T) < L[..., None]
        v = common.masked_time_weights(tau, valid, p["alpha_fastapp"], dtype=d.dtype)
        e = -jnp.einsum("...tg,...t->...g", d, u, precision=hp)
        approach = d[..., :-1, :] - d[..., 1:, :]  # (..., T−1, G)
        f = jnp.einsum("...tg,...t->...g", approach, v, precision=hp)
        return e, f * (L[..., None] - 1).astype(f.dtype)

    def _scores(self, xyz, goals, goal_mask, seen) -> Float[Array, "... G"]:
        """s_k = β_E E_k + β_F F_k on real goals, 0 on padded slots."""
        p = self._constrained()
        e, f = self.terms(xyz, goals, seen)
        return jnp.where(goal_mask, p["beta_effdist"] * e + p["beta_fastapp"] * f, 0.0)

    def parameters(self) -> dict[str, float]:
        """The fitted values: beta_effdist, beta_fastapp (1/m), alpha_effdist, alpha_fastapp,
        and effdist_share = β_E / (β_E + β_F)."""
        p = self._scalar_parameters()
        p["effdist_share"] = p["beta_effdist"] / (p["beta_effdist"] + p["beta_fastapp"])
        return p

    def describe(self) -> str:
        """The fitted parameters with their units, in words."""
        p = self.parameters()
        return "\n".join(
            [
                "Distance/approach mixture observer (EffDist-like + FastApp-like terms):",
                f"  share of the distance (EffDist) term {p['effdist_share']:.1%}, of the "
                f"approach (FastApp) term {1 - p['effdist_share']:.1%};",
                f"  distance term: temperature β_E = {p['beta_effdist']:.3g} per metre of "
                f"time-weighted mean distance, time weighting (1 − t)^α_E with "
                f"α_E = {p['alpha_effdist']:.3g}: " + _alpha_words(p["alpha_effdist"]),
                f"  approach term: temperature β_F = {p['beta_fastapp']:.3g} per metre of "
                f"time-weighted mean approach (over the whole motion), time weighting "
                f"(1 − t)^α_F with α_F = {p['alpha_fastapp']:.3g}: "
                + _alpha_words(p["alpha_fastapp"]),
            ]
        )


# ------------------------------------------------------------------ registry

ARCHETYPES: dict[str, type[_Archetype]] = {
    "dragan": LearnableDragan,
    "viewpoint": LearnableViewpoint,
    "mixture": DistanceApproachMixture,
}


def make_archetype(name: str, **init) -> _Archetype:
    """The archetype called ``name`` ("dragan", "viewpoint" or "mixture") at its default
    (or ``init``) parameters. Archetypes are deterministic: no random initialisation."""
    if name not in ARCHETYPES:
        raise ValueError(f"model: expected one of {tuple(ARCHETYPES)}, got {name!r}")
    return ARCHETYPES[name](**init)


@functools.cache
def _graphdef(name: str) -> nnx.GraphDef:
    return nnx.split(make_archetype(name))[0]


def _archetype_model(name: str, params) -> _Archetype:
    return nnx.merge(_graphdef(name), params)


def _archetype_logits(
    name: str, params, xyz: Float[Array, "T 3"], goals, goal_mask
) -> Float[Array, " 8"]:
    check_observer_inputs(xyz, goals, goal_mask)
    model = _archetype_model(name, params)
    return model(jnp.asarray(xyz), jnp.asarray(goals), jnp.asarray(goal_mask, bool))


def _archetype_prefix(
    name: str, params, xyz: Float[Array, "T 3"], goals, goal_mask, seen
) -> Float[Array, " 8"]:
    check_observer_inputs(xyz, goals, goal_mask)
    check_seen(seen, jnp.shape(xyz)[0])
    model = _archetype_model(name, params)
    return model.prefix(
        jnp.asarray(xyz), jnp.asarray(goals), jnp.asarray(goal_mask, bool), jnp.asarray(seen)
    )


def archetype_observer(name: str, **init) -> Observer:
    """The archetype called ``name`` at its default (or ``init``) parameters as an
    :class:`~slotv_jax.observers.observer.Observer`: ``config`` is ``name``, ``params`` the
    archetype's ``nnx`` parameters (its pytree leaves, on their unconstrained scales), and
    ``describe()``/``parameters()`` the archetype's. Inputs are checked as
    :func:`slotv_jax.load_observer`'s are.

    >>> obs = archetype_observer("mixture", beta_effdist=15.0)
    >>> round(obs.parameters()["effdist_share"], 2)
    0.75
    """
    params = nnx.split(make_archetype(name, **init))[1]
    return Observer(
        logits_fn=_archetype_logits,
        prefix_fn=_archetype_prefix,
        params=params,
        config=name,
        name=name,
        model_fn=_archetype_model,
    )
