"""Cameras any backend can use: OpenCV's VideoCapture on a device, a file or a URL
(``camera.py``), the V4L2 controls a host sets and reads back (``capture_settings.py``,
``v4l2_devices.py``), telling a frozen camera from a live one (``frozen_frames.py``) and
whether a picture is sharp and exposed well enough (``picture_quality.py``).

Why a package of its own, outside a robot's folder: a camera over the table is not the
YuMi's; a UR5e's backend, or a lab's own, reads its pictures the same way (docs/
ARCHITECTURE.md, "A new host backend"). Numpy and OpenCV only, as a robot host installs.
"""
