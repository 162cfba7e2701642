"""Perception: what an image says (the cube's pose, the goal, success, violation) and
how a camera pixel maps to the table (the homography of an arm's calibration).

Why a room: the fleet loop must decide success and violation the same way on the twin
and in the lab, and the YuMi backend runs this on the robot host itself; so it is
numpy and cv2 only, on ``testbed.core``, importable by ``drivers`` and ``gui``.
"""
