"""Training and evaluating observers: configs and presets (:mod:`.config`), batches
(:mod:`.types`), losses (:mod:`.losses`), the trainer (:mod:`.trainer`), evaluation
(:mod:`.evaluate`), checkpoints (:mod:`.checkpoint`), the device mesh (:mod:`.devices`), groups
of runs side by side (:mod:`.schedule`, :mod:`.parallel`) and many processes
(:mod:`.distributed`).
"""
