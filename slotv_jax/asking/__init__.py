"""Choosing what to ask people next: active selection of stimuli (motions × stop times τ).

:mod:`.selection` trains an ensemble of observers on the answers so far (the count
likelihood of :mod:`slotv_jax.answers.fitting`) and ranks candidate stimuli by a criterion
(random, uncertainty, margin, error, BALD, EPIG). It imports :mod:`slotv_jax.answers` and the
library rooms below it, and nothing of the web study: rendering a chosen round and serving
it is :mod:`slotv_jax.study.rounds`' job. :mod:`.replay` replays selection on a pool
whose answers are known (a labeler's labels, simulated guesses): strategies × seeds side by
side, in rounds or in one pass, beside oracles that read the labels.
"""
