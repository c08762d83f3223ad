"""Shared by the planning probes of this folder (not part of the package): the planning
experiment's problems with their straight lines and oracle plans, the gain a learned
observer's plans keep, and how well its planning gradient points where the oracle's does.

The alignment: for each problem, g = ∇_xyz log P(target | ξ_straight) of an observer at the
interior waypoints and the covariant direction A⁻¹g (A the planner's smoothness metric);
the cosine in that metric, gᵀA⁻¹g_oracle / √(gᵀA⁻¹g · g_oracleᵀA⁻¹g_oracle).
"""

from pathlib import Path

import jax
import numpy as np

from slotv_jax import data as data_lib
from slotv_jax import planning
from slotv_jax.experiments import planning as PE

EVAL_SPLITS = ("trajectory_test", *PE.SPLITS)  # the accuracies the probes print


def planning_gradients(obs, xyz, goals, mask, target) -> np.ndarray:
    """∇_xyz log P(target | xyz) at the interior waypoints, (n, T − 2, 3), float64."""

    def log_p(x, g, m, t):
        return jax.nn.log_softmax(obs(x, g, m))[t]

    grads = jax.jit(jax.vmap(jax.grad(log_p)))(xyz, goals, mask, target)
    return np.asarray(grads, np.float64)[:, 1:-1]


def metric_cosines(grads: np.ndarray, ref: np.ndarray, a_inv: np.ndarray) -> np.ndarray:
    """Per problem, the cosine of ``grads`` with ``ref`` in the metric ``a_inv`` (A⁻¹)."""
    d = np.einsum("ij,njc->nic", a_inv, grads)
    d_ref = np.einsum("ij,njc->nic", a_inv, ref)
    return (ref * d).sum((1, 2)) / np.sqrt((ref * d_ref).sum((1, 2)) * (grads * d).sum((1, 2)))


class Problems:
    """The planning experiment's held-out problems of ``preset`` for one ``family``: the
    dataset (train and :data:`EVAL_SPLITS`), the straight lines, the oracle's plans and
    gradients, and the scoring of a learned observer's plans."""

    def __init__(self, preset: str, family: str):
        self.cfg, self.family = PE.PRESETS[preset](), family
        self.ds = data_lib.generate_dataset(
            self.cfg.data,
            data_lib.dataset_dir(Path("data"), self.cfg.data),
            splits=("train", *EVAL_SPLITS),
            progress=False,
        )
        p = PE.make_problems(PE.held_out_scenes(self.cfg, self.ds))
        self.goals, self.mask, self.target = p["goals"], p["goal_mask"], p["target"]
        oracle = planning.labeler_observer(family)
        planner = planning.make_planner({"oracle": oracle}, self.cfg.planner)
        self.straight = planner.straight_line(self.goals, self.mask, self.target)
        self.xyz0 = np.asarray(self.straight.xyz)
        self.a_inv = planning.metric_inverse(self.xyz0.shape[1] - 2)
        self.g_ref = self.gradients(oracle)
        self.y_straight = self.true_y(self.straight.xyz)
        self.y_oracle = self.true_y(planner.plan_problems(self.straight).xyz)

    def true_y(self, xyz) -> np.ndarray:
        """The true labeler's probability of each problem's target for the paths ``xyz``."""
        y = PE.true_labels(self.family, np.asarray(xyz), self.goals, self.mask)
        return y[np.arange(len(self.target)), self.target]

    def gradients(self, obs) -> np.ndarray:
        return planning_gradients(obs, self.xyz0, self.goals, self.mask, self.target)

    def alignment(self, obs) -> float:
        """Mean cosine (A⁻¹ metric) of ``obs``'s planning gradient with the oracle's."""
        return float(metric_cosines(self.gradients(obs), self.g_ref, self.a_inv).mean())

    def score(self, obs) -> tuple[float, float]:
        """Plan every problem with ``obs``: (the fraction of the oracle's gain in true mean
        y_target kept, the fraction of problems whose true y_target fell)."""
        res = jax.jit(jax.vmap(lambda p: planning.plan(obs, p, self.cfg.planner)))(self.straight)
        y = self.true_y(res.xyz)
        gain = self.y_oracle.mean() - self.y_straight.mean()
        return float((y.mean() - self.y_straight.mean()) / gain), float(
            (y < self.y_straight).mean()
        )
