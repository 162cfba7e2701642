"""The lab: the commands of a lab's day with its robots, and their rehearsal.

Why a room of its own: a lab's day is calibrate every arm (``calibrate``: ``testbed
calibrate``), check every host, camera and arm before a trial (``preflight``: ``testbed
check``), put this checkout's build on the hosts (``deploy``: ``testbed deploy``), and,
before touching a robot at all, rehearse the whole physical protocol on
hardware twins behind real sshds (``rehearsal``: ``testbed rehearse``, with the twins
each host's backend declares and their sshds in ``hardware_twin``, the twins' side
channel in ``lab_client``, the lab's humans in ``lab_humans``, the truth and its scoring
in ``twin_truth`` and the true camera's figures in ``camera_model``). These
are the only commands that drive the physical path itself rather than a trial.

It is the only room of ``testbed`` besides ``testbed/experiments/build.py`` that
reaches ``drivers``, ``gui`` and ``sim_twin``, and it does so only lazily, inside the
functions that need them (never at module level), so importing it starts and imports
nothing of theirs. It builds on ``testbed.core``, ``perception``, ``records`` and
``experiments``; nothing in ``testbed`` but the cli imports it.
"""
