"""The ABB YuMi (IRB 14000) host, as one package: its backend, its controller clients
and its camera together.

Why together: everything that makes a YuMi a fleet host -- the backend that plans pushes
from the picture (``backend.py``), the controller seam (``yumi_controller.py``), the one
controller client over Robot Web Services (``rws_controller.py``, for a lab's IRC5 and the
hardware twin alike), what the controller says of itself (``controller_state.py``), its
login (``credentials.py``), the factory (``controllers.py``) and the overhead camera
(``camera.py``) -- changes together and with nothing else, as LeRobot keeps each device's
contract, config and factory side by side. Another robot would get a package of its own
next to this one; ``drivers.backends.make_backend`` imports this one lazily, so only an
agent started with ``--backend yumi`` loads it. Importing the package imports nothing.
"""
