"""The controller of Interactive Fleet Learning (Fleet-DAgger): the core of the product.

Its rooms, each with one reason to change (docs/ARCHITECTURE.md draws the arrows
allowed between them; pyproject.toml's import-linter contracts enforce them):

* ``core``: the types, the config, the hosts and humans contracts, the wrapper bases,
  interrupts and atomic writes: what every other room (drivers and gui included) meets
  through; imports nothing of the project.
* ``perception``: the cube, the goal, success and violation from an image; the
  image-to-table homography.
* ``records``: a run's folder, its steps, its metrics, its data store.
* ``learning``: the policy ensemble and critics (torch).
* ``fleet``: the loop, the allocator, the priority functions, the algorithm registry,
  thresholds (no torch, no drivers, no gui).
* ``datasets``: a run's data as episodes, npz or LeRobot datasets, and back.
* ``experiments``: trials, protocols, sweeps, reports, progress, pretraining, the Ray
  fan-out, and ``build`` (the hosts and humans of a config).
* ``lab``: calibration, preflight and the rehearsal against hardware twins.
* ``cli``: the ``testbed`` command, one registry entry per verb.

``import testbed`` (any room) never imports a driver, a console or the twin: only
``experiments.build`` and ``lab`` reach them, inside functions.
"""
