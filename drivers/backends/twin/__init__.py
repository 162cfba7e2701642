"""The twin backend: a PyBullet cell (``sim_twin.TwinCell``) served like a robot host.

One folder, as every backend: ``twin_host.py`` (its host model: the config fields it
adds), ``twin_backend.py`` (the ``HostBackend``s the agent serves), ``twin_plugin.py``
(the declaration the registry finds: ``testbed.core.backend_registry``).
"""

from __future__ import annotations

from drivers.backends.twin.twin_backend import CannedTwinBackend, TwinBackend, canned_image

__all__ = ["CannedTwinBackend", "TwinBackend", "canned_image"]
