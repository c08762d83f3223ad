"""Studies with people, as one command and one public face: ``python -m slotv_jax.study``
(:mod:`.cli`: import, show, train, cv, stimuli, serve, simulate, export, next) and the next
round of a running study (:mod:`.rounds`, which asks :mod:`slotv_jax.asking` what to show and
renders it with :mod:`slotv_jax.webstudy`).

The work lives in three rooms below this one, one concern each:

- :mod:`slotv_jax.answers`: people's answers as data (format, files, CSV import), fitting
  observers on them, cross-validation, simulated participants;
- :mod:`slotv_jax.asking`: choosing what to ask next (:mod:`slotv_jax.asking.selection`);
- :mod:`slotv_jax.webstudy`: running a study in the browser (stimuli, design, database,
  server, static page, participants over HTTP, export).

This package re-exports the public names of :mod:`slotv_jax.answers` (``from
slotv_jax.study import load_study, train_study, ...`` keeps working) and the module
:mod:`slotv_jax.asking.selection` as ``slotv_jax.study.selection``.
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
from slotv_jax.answers.simulate import (
    check_taus,
    prefix_labels,
    simulate_guesses,
    simulate_study,
    study_from_guesses,
)
from slotv_jax.answers.storage import (
    load_study,
    save_study,
)
from slotv_jax.answers.tables import (
    ImportReport,
    read_tables,
)
from slotv_jax.asking import selection

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
    "load_study",
    "make_study",
    "model_metrics",
    "prefix_labels",
    "prefix_scores",
    "read_tables",
    "row_metrics",
    "save_study",
    "selection",
    "simulate_guesses",
    "simulate_study",
    "study_data",
    "study_from_guesses",
    "study_loss",
    "study_trainer",
    "train_study",
]
