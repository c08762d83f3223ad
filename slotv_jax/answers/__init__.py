"""People's answers as data, and observers fitted on them.

This room holds what a study's goal guesses *are* and what is learned from them, whoever
collected them (a web study, a spreadsheet, a simulation):

- :mod:`.format`: the :class:`Study` arrays (trajectories, goals, answer rows of counts at a
  stop time τ) and their checks;
- :mod:`.storage`: the study ``.npz`` file (checksummed, no pickle);
- :mod:`.tables`: CSV / JSON tables of trajectories, goals and answers -> a :class:`Study`;
- :mod:`.fitting`: the count likelihood of answers on the prefixes people saw, and training
  any observer on it with the one trainer;
- :mod:`.crossval`: metrics, the hand-crafted observers with a fitted β, K-fold
  cross-validation;
- :mod:`.simulate`: simulated participants drawn from a labeler, assembled into a study.

It imports the library rooms below it (core, world, observers, training) and nothing about
how answers are collected (:mod:`slotv_jax.webstudy`) or chosen (:mod:`slotv_jax.asking`).
This package re-exports its modules' public names.
"""

from slotv_jax.answers.crossval import (
    cross_validate,
    cv_table,
    fit_beta,
    labeler_probs,
    labeler_visible,
    model_metrics,
    row_metrics,
)
from slotv_jax.answers.fitting import (
    ANSWERS,
    StudyData,
    answer_logits,
    count_nll,
    prefix_scores,
    study_data,
    study_loss,
    study_trainer,
    train_study,
)
from slotv_jax.answers.format import (
    BETA_RANGE,
    FORMAT,
    PROB_FLOOR,
    TAU_RTOL,
    Study,
    make_study,
)
from slotv_jax.answers.pool_file import (
    load_pool,
    pool_observer,
    save_pool,
)
from slotv_jax.answers.simulate import (
    check_taus,
    prefix_labels,
    simulate_guesses,
    simulate_study,
    study_from_guesses,
    study_from_labels,
)
from slotv_jax.answers.storage import (
    load_study,
    save_study,
)
from slotv_jax.answers.tables import (
    ImportReport,
    read_tables,
)

__all__ = [
    "ANSWERS",
    "BETA_RANGE",
    "FORMAT",
    "PROB_FLOOR",
    "TAU_RTOL",
    "ImportReport",
    "Study",
    "StudyData",
    "answer_logits",
    "check_taus",
    "count_nll",
    "cross_validate",
    "cv_table",
    "fit_beta",
    "labeler_probs",
    "labeler_visible",
    "load_pool",
    "load_study",
    "make_study",
    "model_metrics",
    "pool_observer",
    "prefix_labels",
    "prefix_scores",
    "read_tables",
    "row_metrics",
    "save_pool",
    "save_study",
    "simulate_guesses",
    "simulate_study",
    "study_data",
    "study_from_guesses",
    "study_from_labels",
    "study_loss",
    "study_trainer",
    "train_study",
]
