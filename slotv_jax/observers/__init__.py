"""Observer models: the four hand-crafted labelers (:mod:`.labelers`, :mod:`.labelling`, SPEC §4),
the parametric archetypes (:mod:`.parametric`, :mod:`.archetypes`) and the SLOT-V and T-REX
networks (:mod:`.models`, SPEC §5, §6), on the maths they share (:mod:`.common`: goal-padding
masks, time weights, Dragan's kernel; the camera projection is the world's,
:func:`slotv_jax.world.scene.camera_coords`).
"""
