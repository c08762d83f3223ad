"""What experiments share: the run presets (:mod:`.presets`: a dataset config, a training
config per method and a number of trials, with the labelers, methods and splits of an
accuracy table and their titles) and the resumable grid of trained cells (:mod:`.grid`).
"""
