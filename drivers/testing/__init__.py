"""Helpers for testing the drivers: real things where they can run here (an OpenSSH
server on loopback, ``sshd.py``) and fakes where they cannot (the ABB YuMi controller,
``fake_yumi.py``).

Why a package of their own: the tests and the benchmarks import them alike, and no
production module carries a test helper; nothing here runs in a trial.
"""
