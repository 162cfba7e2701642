"""A run's records: its folder, its steps (steps.jsonl), its metrics, its data store.

Why a room: the records are the trial's ground truth, written by the loop, read back by
resume, the report, the export and the Ray fan-out; every number the project reports is
recomputed from them. It imports only ``testbed.core`` (numpy, no torch), so a tool or a
notebook reads a run without the learning stack.
"""
