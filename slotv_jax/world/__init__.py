"""The world around the robot: scenes and observer cameras (:mod:`.scene`, SPEC §2) and random
pick-and-place trajectories (:mod:`.trajectories`, SPEC §3).
"""
