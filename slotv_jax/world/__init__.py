"""The world around the robot: scenes and observer cameras (:mod:`.scene`, :ref:`concepts-cameras`)
and random pick-and-place trajectories (:mod:`.trajectories`, :ref:`concepts-trajectories`).
"""
