"""What experiments share: the run presets (:mod:`.presets`: a dataset config, a training
config per method and a number of trials, with the labelers, methods and splits of an
accuracy table and their titles), the resumable grid of trained cells (:mod:`.grid`), the
sample-efficiency curves (:mod:`.curves`), pooled summaries over trials and seeds
(:mod:`.summary`), the figure style (:mod:`.figures`), what a results document keeps of
its run (:mod:`.record`) and the flags and ``--report`` the commands share
(:mod:`.command`). It imports the library rooms below it, never an experiment.
"""
