"""check_backend on every backend, and on broken ones (it must say which rule broke)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import pytest
from driver_fakes import make_yumi, twin_picture

from drivers.backends.base import ArmOutcome, ArmView, HostBackend
from drivers.backends.twin import CannedTwinBackend, TwinBackend
from drivers.conformance import check_backend
from drivers.errors import ConformanceError


@pytest.mark.parametrize("seed", [0, 11])
def test_twin_backend_conforms(seed: int) -> None:
    with TwinBackend(seed) as backend:
        check_backend(backend)


def test_twin_backend_with_one_unmirrored_arm_conforms() -> None:
    with TwinBackend(2, arms=("solo",), mirror=(False,)) as backend:
        check_backend(backend)


def test_canned_twin_backend_conforms() -> None:
    check_backend(CannedTwinBackend(3))


def test_yumi_backend_conforms(tmp_path: Path) -> None:
    backend, ctrl = make_yumi(tmp_path, [twin_picture(5)])
    check_backend(backend)
    assert ctrl.programs  # it really moved (the fake recorded the programs)
    backend.close()


def test_yumi_backend_with_a_violating_arm_conforms(tmp_path: Path) -> None:
    backend, _ = make_yumi(tmp_path, [twin_picture(6, {"right": (0.5, 0.99)})])
    assert backend.observe()["right"].violating
    check_backend(backend)
    backend.close()


class Broken(HostBackend):
    """CannedTwinBackend with one rule broken at a time."""

    kind = "broken"

    def __init__(self, flaw: str) -> None:
        self.inner = CannedTwinBackend(0)
        self.flaw = flaw

    @property
    def arm_names(self) -> tuple[str, ...]:
        return self.inner.arm_names

    @property
    def mirror(self) -> tuple[bool, ...]:
        return (True,) if self.flaw == "mirror" else self.inner.mirror

    def observe(self) -> dict[str, ArmView]:
        views = self.inner.observe()
        v = views["left"]
        if self.flaw == "shape":
            views["left"] = ArmView(v.image[:63], v.violating, v.goal, v.expert_action)
        elif self.flaw == "goal":
            views["left"] = ArmView(v.image, v.violating, (0.5, 1.5), v.expert_action)
        elif self.flaw == "png":
            views["left"] = ArmView(np.zeros_like(v.image), v.violating, v.goal,
                                    v.expert_action, v.png)
        elif self.flaw == "order":
            views = dict(reversed(list(views.items())))
        return views

    def push(self, faces: Mapping[str, int]) -> dict[str, ArmOutcome]:
        out = self.inner.push(faces)
        if self.flaw == "extra":
            out["right"] = ArmOutcome(False, False)
        if self.flaw == "both":
            out = {a: ArmOutcome(True, True) for a in out}
        if self.flaw == "readings":
            out = {a: ArmOutcome(o.success, o.violation, readings={"push s": 1.0})
                   for a, o in out.items()}
        return out

    def reset(self, arms: Sequence[str]) -> dict[str, bool]:
        return {a: False for a in self.inner.reset(arms)} if self.flaw == "reset" else (
            self.inner.reset(arms))

    def rest(self) -> None:
        pass

    def close(self) -> None:
        pass


@pytest.mark.parametrize(("flaw", "match"), [
    ("shape", r"image must be a \(64, 64, 3\) uint8 array"),
    ("goal", "goal must be a tuple of two floats in"),
    ("png", "does not survive the wire"),
    ("order", "a view for each arm in order"),
    ("mirror", "mirror must be one bool per arm"),
    ("extra", "outcome for exactly"),
    ("both", "cannot both succeed and violate"),
    ("readings", r"readings name 'push s' is not an identifier"),
    ("reset", "reset said done=False"),
])
def test_broken_backends_are_named(flaw: str, match: str) -> None:
    with pytest.raises(ConformanceError, match=match):
        check_backend(Broken(flaw))
