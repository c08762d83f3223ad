"""Observer models: the four hand-crafted labelers (:mod:`.labelers`, :mod:`.labelling`,
:ref:`concepts-labelers`), the parametric archetypes (:mod:`.parametric`, :mod:`.archetypes`) and
the SLOT-V and T-REX networks (:mod:`.models`, :ref:`concepts-slotv`, :ref:`concepts-trex`), on the
maths they share (:mod:`.common`: goal-padding masks, time weights, Dragan's kernel; the camera
projection is the world's,
:func:`slotv_jax.world.scene.camera_coords`).
"""
