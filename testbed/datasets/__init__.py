"""A run's data as datasets others read (``testbed export``), and back (``testbed train``).

Why a package: the run's data store (``testbed.records.store``) is built for the fleet
loop -- appending, resuming, step-major, one record per arm per step. Learning code
outside the testbed (LeRobot, Sirius-style intervention learning, a notebook) wants
*episodes* in a format it already reads, and ``testbed train --data`` wants such a
dataset (or a run folder) back as a learner's data. This package is that translation,
one module per reason to change:

* ``sources``: which runs and demonstrations files an export reads;
* ``episodes``: the episode model (columns, codes) and cutting runs and demos into it;
* ``npz``: one npz that numpy alone reads (``--format npz``);
* ``lerobot`` (with ``video`` and ``stats``): a LeRobot v3 dataset (``--format lerobot``,
  the optional ``export`` extra: pyarrow, PyAV);
* ``training``: frames back as the learner's data (human labels, critic transitions);
* ``dataset_io``: the verbs' entry points, ``export`` and ``load_frames``, choosing the
  format.

docs/notes/data.md says what was measured and checked.
"""
