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

from slotv_jax import answers
from slotv_jax.answers import *  # noqa: F403  (the names of answers.__all__, listed once there)
from slotv_jax.asking import selection

__all__ = ["selection", *answers.__all__]
