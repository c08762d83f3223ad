"""Observers learned from people: the study format (:mod:`.format`), files (:mod:`.storage`),
CSV import (:mod:`.tables`), fitting on goal guesses (:mod:`.fitting`), cross-validation
against the hand-crafted observers (:mod:`.crossval`), simulated participants
(:mod:`.simulate`) and the command line (:mod:`.cli`, ``python -m slotv_jax.study``).

Running a study with people: stimulus sets and their rounds (:mod:`.stimuli`, rendered by
:mod:`.make_stimuli`), the design (:mod:`.design`), the answers database
(:mod:`.database`), the server (:mod:`.service`, :mod:`.server`, ``static/``), export
into the import format (:mod:`.export`), participants over HTTP (:mod:`.client`) and
their commands (:mod:`.web_cli`); import them from their modules.

This package re-exports the public names of its modules.
"""

from slotv_jax.study.crossval import (
    cross_validate,
    cv_table,
    fit_beta,
    labeler_probs,
    labeler_visible,
    model_metrics,
    row_metrics,
)
from slotv_jax.study.fitting import (
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
from slotv_jax.study.format import (
    BETA_RANGE,
    FORMAT,
    PROB_FLOOR,
    TAU_RTOL,
    Study,
    make_study,
)
from slotv_jax.study.simulate import (
    check_taus,
    prefix_labels,
    simulate_guesses,
    simulate_study,
    study_from_guesses,
)
from slotv_jax.study.storage import (
    load_study,
    save_study,
)
from slotv_jax.study.tables import (
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
    "load_study",
    "make_study",
    "model_metrics",
    "prefix_labels",
    "prefix_scores",
    "read_tables",
    "row_metrics",
    "save_study",
    "simulate_guesses",
    "simulate_study",
    "study_data",
    "study_from_guesses",
    "study_loss",
    "study_trainer",
    "train_study",
]
