"""What every part of the product meets through: types, config, contracts, safe writes.

Why a room of its own: ``drivers`` (the host side) and ``gui`` (the consoles) implement
contracts the fleet loop calls (``hosts.Hosts``, ``humans.Humans``) and exchange the
types of ``types``; if those lived beside the loop, the hosts and consoles would import
the roof to reach the foundation. So ``core`` imports nothing of the project, stays
light (numpy, and pydantic in ``config`` only) and is Python 3.10 code, for a robot
host's Python (checked by vermin in tests/test_architecture.py).
"""
