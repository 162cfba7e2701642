"""Planning the lab: ``testbed plan``, how many people for how many arms, fitted from
finished runs and simulated (``plan_fit.py``, ``plan_trouble.py``, ``plan_sim.py``,
``plan.py``), checked against a measured sweep (``plan_check.py``), and how many trials
a protocol needs (``plan_trials.py``).

Why a room of its own: it reads results and the allocator's rules and never runs a
fleet; running experiments does not need it (docs/ARCHITECTURE.md).
"""
