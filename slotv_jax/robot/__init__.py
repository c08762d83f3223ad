"""The robot: Franka Emika Panda kinematics through MuJoCo MJX and the MJCF models
(:mod:`.kinematics`, :ref:`concepts-robot`).
"""
