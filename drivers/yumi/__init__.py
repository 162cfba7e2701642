"""The ABB YuMi (IRB 14000) host, as one package: its backend, its controller clients
and its camera together.

Why together: everything that makes a YuMi a fleet host -- the backend that plans pushes
from the picture (``backend.py``), the controller seam and the real controller's client
(``yumi_controller.py``), the hardware twin's client (``twin_controller.py``), the factory
that picks one from the controller URL (``controllers.py``) and the overhead camera
(``camera.py``) -- changes together and with nothing else, as LeRobot keeps each device's
contract, config and factory side by side. Another robot would get a package of its own
next to this one; ``drivers.backends.make_backend`` imports this one lazily, so only an
agent started with ``--backend yumi`` loads it. Importing the package imports nothing.
"""
