"""``check_backend``: does a host backend keep the ``HostBackend`` contract?

Why (as Gymnasium's ``check_env``): the twin, the ABB YuMi and any future robot are
driven by the same agent and the same fleet; a backend that returns a 63x64 image, a
goal outside the frame, an outcome for an arm it was not asked to push, or that moves a
violating arm, breaks the trial far from its cause. One check, run by the tests on
every backend, catches it at the boundary and says which rule was broken.

What it does to the backend: observes, pushes every non-violating arm at once, pushes
one arm alone, checks a push on a violating arm is refused (when one is violating),
resets one arm, rests. It moves the robot: run it on a twin, a fake controller, or a
real cell that is clear and supervised.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from typing import Any

import numpy as np

from drivers.backends.base import IMAGE_SHAPE, ArmOutcome, ArmView, HostBackend
from drivers.errors import ConformanceError
from drivers.png import decode_png
from drivers.wire import encode_image, reading_problem
from testbed.core.config import NAME_PATTERN
from testbed.core.types import NUM_ACTIONS


def _fail(rule: str) -> ConformanceError:
    return ConformanceError(f"backend does not conform: {rule}")


def _check_views(backend: HostBackend, views: Any) -> dict[str, ArmView]:
    arms = backend.arm_names
    if not isinstance(views, Mapping):
        raise _fail(f"observe() must return a dict arm -> ArmView, got {type(views).__name__}")
    if list(views) != list(arms):
        raise _fail(f"observe() must return a view for each arm in order {list(arms)}, got "
                    f"{list(views)}")
    for arm, v in views.items():
        if not isinstance(v, ArmView):
            raise _fail(f"observe()[{arm!r}] must be an ArmView, got {type(v).__name__}")
        img = v.image
        if not isinstance(img, np.ndarray) or img.shape != IMAGE_SHAPE or img.dtype != np.uint8:
            got = (img.shape, img.dtype) if isinstance(img, np.ndarray) else type(img).__name__
            raise _fail(f"arm {arm!r}: image must be a {IMAGE_SHAPE} uint8 array, got {got}")
        if type(v.violating) is not bool:
            raise _fail(f"arm {arm!r}: violating must be a bool, got {v.violating!r}")
        if (not isinstance(v.goal, tuple) or len(v.goal) != 2
                or not all(isinstance(g, float) and math.isfinite(g) and 0 <= g <= 1
                           for g in v.goal)):
            raise _fail(f"arm {arm!r}: goal must be a tuple of two floats in [0, 1], "
                        f"got {v.goal!r}")
        if v.expert_action is not None and (type(v.expert_action) is not int
                                            or not 0 <= v.expert_action < NUM_ACTIONS):
            raise _fail(f"arm {arm!r}: expert_action must be None or a face, "
                        f"got {v.expert_action!r}")
        if v.violating and v.expert_action is not None:
            raise _fail(f"arm {arm!r}: a violating arm has no expert push (got "
                        f"{v.expert_action})")
        png = v.png if v.png is not None else encode_image(img)
        back = decode_png(png, IMAGE_SHAPE, f"arm {arm!r}")
        if not np.array_equal(back, img):
            raise _fail(f"arm {arm!r}: the image does not survive the wire (PNG round trip "
                        f"differs; a cached png must encode exactly the image)")
    return dict(views)


def _check_outcomes(what: str, outcomes: Any, expected: list[str]) -> dict[str, ArmOutcome]:
    if not isinstance(outcomes, Mapping) or sorted(outcomes) != sorted(expected):
        got = sorted(outcomes) if isinstance(outcomes, Mapping) else type(outcomes).__name__
        raise _fail(f"{what} must return an outcome for exactly {sorted(expected)}, got {got}")
    for arm, o in outcomes.items():
        if not isinstance(o, ArmOutcome) or type(o.success) is not bool or type(
                o.violation) is not bool:
            raise _fail(f"{what}[{arm!r}] must be an ArmOutcome of two bools, got {o!r}")
        if o.success and o.violation:
            raise _fail(f"{what}[{arm!r}]: a push cannot both succeed and violate")
        if (why := reading_problem(o.readings)) is not None:
            raise _fail(f"{what}[{arm!r}]: readings {why} (the agent would fault the arm)")
    return dict(outcomes)


def _expect_value_error(what: str, fn: Any) -> None:
    try:
        fn()
    except ValueError:
        return
    except Exception as exc:
        raise _fail(f"{what} must raise ValueError, raised {type(exc).__name__}: {exc}") from exc
    raise _fail(f"{what} must raise ValueError, it returned")


def check_backend(backend: HostBackend, *, pushes: int = 3) -> None:
    """Raise :class:`~drivers.errors.ConformanceError` naming the first broken rule."""
    arms = backend.arm_names
    if not isinstance(arms, tuple) or not arms or len(set(arms)) != len(arms):
        raise _fail(f"arm_names must be a non-empty tuple of distinct names, got {arms!r}")
    for a in arms:
        if not isinstance(a, str) or not re.match(NAME_PATTERN, a):
            raise _fail(f"arm name {a!r} must match {NAME_PATTERN}")
    mirror = backend.mirror
    if not isinstance(mirror, tuple) or len(mirror) != len(arms) or any(
            type(m) is not bool for m in mirror):
        raise _fail(f"mirror must be one bool per arm, got {mirror!r}")
    if not isinstance(backend.kind, str) or not backend.kind or backend.kind == "abstract":
        raise _fail("kind must name the backend")

    views = _check_views(backend, backend.observe())
    for _ in range(pushes):
        free = [a for a in arms if not views[a].violating]
        if free:
            faces = {a: (views[a].expert_action or 0) for a in free}
            _check_outcomes("push(all free arms)", backend.push(faces), free)
        views = _check_views(backend, backend.observe())
    one = arms[0]
    out = _check_outcomes("push(one arm)", backend.push({one: 2}), [one])
    views = _check_views(backend, backend.observe())
    if out[one].violation and not views[one].violating:
        raise _fail(f"arm {one!r}: a push that violated must leave the arm violating")
    for arm in arms:
        if views[arm].violating:
            refused = _check_outcomes("push(violating arm)", backend.push({arm: 0}), [arm])
            o = refused[arm]
            if o.success or o.violation or o.error is not None:
                raise _fail(f"arm {arm!r}: a push on a violating arm must be refused "
                            f"(no success, no violation, no error), got {o}")
    _expect_value_error("push with face 4", lambda: backend.push({one: NUM_ACTIONS}))
    _expect_value_error("push of an unknown arm", lambda: backend.push({"no-such-arm": 0}))
    _expect_value_error("reset of an unknown arm", lambda: backend.reset(["no-such-arm"]))
    done = backend.reset([one])
    if not isinstance(done, Mapping) or list(done) != [one] or type(done[one]) is not bool:
        raise _fail(f"reset([{one!r}]) must return {{{one!r}: bool}}, got {done!r}")
    views = _check_views(backend, backend.observe())
    if done[one] == views[one].violating:
        raise _fail(f"arm {one!r}: reset said done={done[one]} but observe() says "
                    f"violating={views[one].violating}")
    backend.rest()
    _check_views(backend, backend.observe())
