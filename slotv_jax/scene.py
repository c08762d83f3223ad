"""Scenes and the observer cameras (:ref:`concepts-cameras`, :ref:`concepts-public-names`) under
their public name.

The code lives in :mod:`slotv_jax.world.scene`; this module keeps the public names of
:ref:`concepts-public-names` (``slotv_jax.scene.camera``).
"""

from slotv_jax.world.scene import (
    Camera,
    Scene,
    SceneConfig,
    camera,
    camera_from_dict,
    camera_label,
    check_camera,
    check_scene,
    check_sees_goals,
    in_view,
    is_camera_file,
    project,
    read_camera_file,
    sample_goal_count,
    sample_scene,
)

__all__ = [
    "Camera",
    "Scene",
    "SceneConfig",
    "camera",
    "camera_from_dict",
    "camera_label",
    "check_camera",
    "check_scene",
    "check_sees_goals",
    "in_view",
    "is_camera_file",
    "project",
    "read_camera_file",
    "sample_goal_count",
    "sample_scene",
]
