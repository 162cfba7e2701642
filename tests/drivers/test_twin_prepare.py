"""The twin agent renders the next observation right after a push or reset (``prepare``):
what ``observe`` then returns is exactly what it would have rendered on request."""

from __future__ import annotations

import numpy as np

from drivers.backends.twin import TwinBackend


def _same(a: dict, b: dict) -> None:
    assert a.keys() == b.keys()
    for arm in a:
        np.testing.assert_array_equal(a[arm].image, b[arm].image)
        assert (a[arm].violating, a[arm].goal, a[arm].expert_action) == (
            b[arm].violating, b[arm].goal, b[arm].expert_action)


def test_prepared_views_are_the_views_observe_renders() -> None:
    ready, fresh = TwinBackend(seed=5), TwinBackend(seed=5)
    try:
        for k in range(4):
            faces = {"left": k % 4, "right": (k + 1) % 4}
            assert ready.push(faces) == fresh.push(faces)
            ready.prepare()
            _same(ready.observe(), fresh.observe())
        # a motion after prepare drops the prepared views
        ready.prepare()
        ready.push({"left": 2})
        fresh.push({"left": 2})
        ready.reset(["right"])
        fresh.reset(["right"])
        _same(ready.observe(), fresh.observe())
    finally:
        ready.close()
        fresh.close()
