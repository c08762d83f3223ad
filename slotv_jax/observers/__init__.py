"""Observer models: the four hand-crafted labelers (:mod:`.labelers`, :mod:`.labelling`, SPEC §4),
the parametric archetypes (:mod:`.parametric`, :mod:`.archetypes`) and the SLOT-V and T-REX
networks (:mod:`.models`, SPEC §5, §6).
"""
