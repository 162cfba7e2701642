"""The people of the fleet: who the humans are and how they answer, as the config says.

Why a room: the people are the scarce resource Fleet-DAgger allocates, and what the
product knows of them (their names, a scripted human's skill, latency and availability,
the web console's settings) is read by the allocation's caller, the consoles and the
report alike. Their schema lives here (the humans contract, what the loop calls, is
``testbed/core/humans.py``); the consoles (``gui``) may import it.
"""
