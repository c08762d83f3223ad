"""See the motion (:ref:`concepts-commands`): the public names of :mod:`slotv_jax.rendering` and the
command ``python -m slotv_jax.render`` (:mod:`slotv_jax.render.cli`).

>>> from slotv_jax import render
>>> frames = render.motion_frames(q, goals, goal_mask, tau=0.6)  # doctest: +SKIP
>>> render.write_video("clip.mp4", frames, fps=30)  # doctest: +SKIP
"""

from slotv_jax.rendering import *  # noqa: F403  (exactly rendering's __all__)
from slotv_jax.rendering import __all__ as __all__
