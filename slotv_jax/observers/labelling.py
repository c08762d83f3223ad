"""Labelling many trajectories at once: :func:`label_all`, one compiled ``jit(vmap)`` of the
four labelers per chunk, with every check that cannot raise inside the compiled call done
per trajectory and reported by index (:ref:`concepts-labelers`, :ref:`concepts-datasets`).

The temperatures and the camera travel together as one :class:`LabelConfig`, checked once
when it is made: :func:`label_all` makes one from its keyword arguments, a dataset's
:class:`slotv_jax.data.DataConfig` holds one, and both label through :func:`label_with`.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float
from tqdm.auto import tqdm

from slotv_jax.core import validation
from slotv_jax.core.progress import has_compiled
from slotv_jax.core.validation import G_MAX
from slotv_jax.observers.labelers import (
    CHUNK_LABELS,
    DEFAULT_BETAS,
    DEPTH_EPS,
    LABELER_NAMES,
    LABELERS,
    _as_camera,
    _check_times,
    _in_front,
    _normalise_times,
    nikolaidis,
)
from slotv_jax.world.scene import Camera


@dataclasses.dataclass(frozen=True)
class LabelConfig:
    """Inverse temperatures of the four labelers (:ref:`concepts-temperatures`), checked once, here,
    and the Nikolaidis camera (checked where it is used: a name needs the scene model).

    The defaults are :data:`slotv_jax.core.defaults.DEFAULT_BETAS`, the labelers' own: four
    times the first version's (5, 7.5, 5 and 5). The paper does not state its
    temperatures, and at ×4 T-REX's accuracy on Dragan labels matches the paper's while
    SLOT-V's does not move (``experiments/fidelity.md``).
    :data:`slotv_jax.data.LABELS_V1` keeps the first version's temperatures.
    """

    beta_dragan: float = DEFAULT_BETAS["dragan"]  # m⁻¹
    beta_nikolaidis: float = DEFAULT_BETAS["nikolaidis"]  # per unit of image-plane distance
    beta_effdist: float = DEFAULT_BETAS["effdist"]  # m⁻¹
    beta_fastapp: float = DEFAULT_BETAS["fastapp"]  # m⁻¹
    camera: str | Camera = "observer"  # a camera name of slotv_jax.scene, or a Camera

    def __post_init__(self):
        for n in LABELER_NAMES:
            validation.check_positive(f"beta_{n}", getattr(self, f"beta_{n}"))

    def betas(self) -> dict[str, float]:
        """``{labeler: β}`` in the order of :data:`LABELER_NAMES`."""
        return {n: float(getattr(self, f"beta_{n}")) for n in LABELER_NAMES}


# ------------------------------------------------------------ bulk labelling

_TRACES = {"label_chunk": 0}  # traces of label_all's compiled chunk (tests check it is one)
_ERRORS = (  # what label_all reports for a bad trajectory, first applicable first
    "xyz: expected finite values; trajectory {i} holds NaN/inf (or coordinates so large "
    "that float32 distances overflow)",
    "goals: expected finite values; trajectory {i} holds NaN/inf",
    "goals: two real goals share the same position (trajectory {i})",
    "xyz: trajectory {i} has point(s) at camera depth <= {eps} m (on or behind the camera plane)",
    "goals: trajectory {i} has real goal(s) at camera depth <= {eps} m (on or behind the "
    "camera plane)",
)


@functools.partial(jax.jit, static_argnames="names")
def _label_chunk(xyz, goals, mask, t, betas, camera, names):
    """``jit(vmap)`` of the public labelers ``names`` over one chunk, and per trajectory
    the checks that cannot raise inside, ``(C, 3)`` (``(C, 5)`` with nikolaidis) in the
    order of ``_ERRORS``. NaN labels flag non-finite points (or an overflow). Nikolaidis
    gives a uniform label when a depth is invalid, which may hide a bad point: its
    point-depth flag here only says "not exactly uniform", and :func:`_recheck_points`
    checks the points of the (few) uniform ones."""
    _TRACES["label_chunk"] += 1

    def one(x, g, m, tt):
        labels = {
            n: nikolaidis(x, g, m, camera, beta=betas[n], t=tt)
            if n == "nikolaidis"
            else LABELERS[n](x, g, m, beta=betas[n], t=tt)
            for n in names
        }
        # Pairs written out: XLA fuses them into one loop (reductions over axes of 3
        # and 8 slots would cost more than labelling with effdist).
        same = [
            m[k] & m[l] & (sum((g[k, j] - g[l, j]) ** 2 for j in range(3)) < 1e-18)
            for k in range(G_MAX)
            for l in range(k)
        ]
        # A NaN/inf point (or an overflow) makes every label of its trajectory NaN.
        finite = [jnp.all(jnp.isfinite(y)) for y in labels.values()]
        goals_finite = jnp.all(jnp.isfinite(g))
        ok = [functools.reduce(jnp.logical_and, finite), goals_finite]
        ok.append(~functools.reduce(jnp.logical_or, same))
        if "nikolaidis" in names:
            uniform = (m / jnp.sum(m)).astype(labels["nikolaidis"].dtype)
            in_front = _in_front(g, camera.pos, camera.rot, m)
            ok += [~jnp.all(labels["nikolaidis"] == uniform), in_front]
        ok[0] |= ~goals_finite  # non-finite goals are reported as such
        return labels, jnp.stack(ok)

    t_axis = None if t is None or t.ndim == 1 else 0
    return jax.vmap(one, in_axes=(0, 0, 0, t_axis))(xyz, goals, mask, t)


def label_all(
    xyz: Float[np.ndarray, "N T 3"],
    goals: Float[np.ndarray, "N 8 3"],
    goal_mask: Bool[np.ndarray, "N 8"],
    *,
    t: Float[np.ndarray, "*N T"] | None = None,
    chunk_size: int | None = None,
    progress: bool = True,
    labelers: Sequence[str] = LABELER_NAMES,
    beta_dragan: float = DEFAULT_BETAS["dragan"],
    beta_nikolaidis: float = DEFAULT_BETAS["nikolaidis"],
    beta_effdist: float = DEFAULT_BETAS["effdist"],
    beta_fastapp: float = DEFAULT_BETAS["fastapp"],
    camera: Camera | str = "observer",
) -> dict[str, np.ndarray]:
    """Label many trajectories (float32): the public labelers under ``jit(vmap)``, chunk by
    chunk. Chunks of ``chunk_size`` (default ``16384 // len(labelers)``) go through one
    compiled function (the last chunk overlaps the one before). On the CPU a float32 JAX
    array is read in place; a NumPy array is copied chunk by chunk (cheaper than one copy
    of the whole).

    Args: ``xyz (N, T, 3)`` (m, T >= 2); ``goals (N, 8, 3)`` and ``goal_mask (N, 8)``, or
    ``(8, 3)`` and ``(8,)`` shared by all; ``t`` optional time stamps, ``(T,)`` or
    ``(N, T)``; ``labelers``: which labels; ``beta_*``: as in :ref:`concepts-temperatures` (traced:
    a new value does not recompile); ``camera``: for nikolaidis. ``labelers`` is a sequence of
    names or one name (``"dragan"``). Returns ``{name: (N, 8)}``.
    Raises ``ValueError`` naming the argument (and the first bad trajectory) for what
    the public labelers reject, and for labels that overflow float32.

    >>> xyz = np.random.default_rng(0).uniform([0.3, -0.4, 0.1], [0.7, 0.4, 0.4], (10, 100, 3))
    >>> goals = np.zeros((8, 3))
    >>> goals[:3] = [[0.4, 0.3, 0.025], [0.5, 0.0, 0.025], [0.6, -0.3, 0.025]]
    >>> y = label_all(xyz, goals, np.arange(8) < 3, progress=False)
    >>> sorted(y), y["dragan"].shape
    (['dragan', 'effdist', 'fastapp', 'nikolaidis'], (10, 8))
    """
    labels = LabelConfig(beta_dragan, beta_nikolaidis, beta_effdist, beta_fastapp, camera)
    return label_with(
        labels, xyz, goals, goal_mask, t=t, chunk_size=chunk_size, progress=progress,
        labelers=labelers,
    )  # fmt: skip


def label_with(
    labels: LabelConfig,
    xyz: Float[np.ndarray, "N T 3"],
    goals: Float[np.ndarray, "N 8 3"],
    goal_mask: Bool[np.ndarray, "N 8"],
    *,
    t: Float[np.ndarray, "*N T"] | None = None,
    chunk_size: int | None = None,
    progress: bool = True,
    labelers: Sequence[str] = LABELER_NAMES,
) -> dict[str, np.ndarray]:
    """:func:`label_all` at the temperatures and camera of ``labels`` (checked when it was
    made): ``{name: y (N, 8)}``, each ``y_k`` as :ref:`concepts-temperatures` defines it at β =
    ``labels.beta_name``.
    """
    if not isinstance(labels, LabelConfig):
        raise ValueError(f"labels: expected a LabelConfig, got {type(labels).__name__}")
    names, (xyz, goals, goal_mask, t) = _bulk_inputs(labelers, xyz, goals, goal_mask, t, chunk_size)
    betas = {n: jnp.float32(getattr(labels, f"beta_{n}")) for n in names}  # traced
    chunk_size = CHUNK_LABELS // len(names) if chunk_size is None else chunk_size
    N, C = len(xyz), min(chunk_size, max(len(xyz), 1))
    out = {n: np.empty((N, G_MAX), np.float32) for n in names}
    ok = np.ones((N, len(_ERRORS)), bool)
    with tqdm(total=N, unit="traj", desc="labelling", disable=not progress) as bar:
        if not has_compiled(_label_chunk):  # the first chunk waits for it
            bar.set_postfix_str("compiling the labelers")
        cam = _as_camera(labels.camera)  # a name is looked up here, not when the config is made
        for start in range(0, N, C):
            lo = min(start, N - C)  # the last chunk overlaps the one before: no padding
            rows = [a[lo : lo + C] for a in (xyz, goals, goal_mask)]
            tt = t[lo : lo + C] if t is not None and t.ndim == 2 else t
            labels, flags = _label_chunk(*rows, tt, betas, cam, names=names)
            for name in names:
                out[name][lo : lo + C] = np.asarray(labels[name])
            ok[lo : lo + C, : flags.shape[-1]] = np.asarray(flags)
            bar.set_postfix_str("", refresh=False)
            bar.update(min(C, N - start))
    if "nikolaidis" in names:
        _recheck_points(ok, xyz, cam)
    if not ok.all():
        i = int(np.flatnonzero(~ok.all(-1))[0])
        raise ValueError(_ERRORS[int(np.argmin(ok[i]))].format(i=i, eps=DEPTH_EPS))
    return out


@jax.jit
def _points_ok(xyz: Float[Array, "n T 3"], pos, rot) -> tuple[Bool[Array, " n"], Bool[Array, " n"]]:
    """Per trajectory: all points finite; all points at depth > ``DEPTH_EPS`` (float32,
    as :func:`_nikolaidis_core` decides)."""
    return jnp.all(jnp.isfinite(xyz), axis=(-2, -1)), _in_front(xyz, pos, rot)


def _recheck_points(ok: np.ndarray, xyz: np.ndarray, cam: Camera) -> None:
    """Check the points of the trajectories whose nikolaidis label is exactly uniform
    (``ok[:, 3]`` False from :func:`_label_chunk`): set their finite (0) and
    point-depth (3) flags. The label of a point behind the camera is uniform, and hides
    a NaN point; any other label shows a NaN point as NaN."""
    rows = np.flatnonzero(~ok[:, 3])
    if rows.size:
        finite, in_front = map(np.asarray, _points_ok(jnp.asarray(xyz[rows]), cam.pos, cam.rot))
        ok[rows, 0] &= finite
        ok[rows, 3] = in_front


def _bulk_inputs(labelers, xyz, goals, goal_mask, t, chunk_size):
    """:func:`label_with`'s boundary checks; its names and arrays (float32, goals and mask
    broadcast to ``(N, ...)``, ``t`` normalised)."""
    names = (labelers,) if isinstance(labelers, str) else tuple(labelers)  # one name
    if not names or any(n not in LABELERS for n in names):
        raise ValueError(f"labelers: expected a non-empty subset of {LABELER_NAMES}, got {names}")
    validation.check_shape("xyz", xyz, (None, None, 3))
    validation.check_real("xyz", xyz)
    validation.check_real("goals", goals)
    N, T = np.shape(xyz)[:2]
    if T < 2:
        raise ValueError(f"xyz: expected at least 2 trajectory points (T >= 2), got T = {T}")
    goals, goal_mask = np.asarray(goals, np.float32), np.asarray(goal_mask)
    goals = np.broadcast_to(goals, (N, *goals.shape)) if goals.ndim == 2 else goals
    if goal_mask.ndim == 1:
        goal_mask = np.broadcast_to(goal_mask, (N, *goal_mask.shape))
    validation.check_shape("goals", goals, (N, G_MAX, 3))
    validation.check_goal_mask("goal_mask", goal_mask, batch_shape=(N,))
    if t is not None:  # normalised in float64 (see _time_weights)
        _check_times("t", t, (T,) if np.ndim(t) == 1 else (N, T))
        t = _normalise_times(np.asarray(t, np.float64), np).astype(np.float32)
    if chunk_size is not None and int(chunk_size) < 1:
        raise ValueError(f"chunk_size: expected a positive integer, got {chunk_size}")
    arrays = (np.asarray(xyz, np.float32), goals, goal_mask.astype(bool, copy=False), t)
    return names, arrays
