"""An interrupt never lands in the middle of a step's or a checkpoint's write."""

from __future__ import annotations

import os
import signal
from collections.abc import Iterator

import pytest

from testbed.core.interrupts import INTERRUPTS, critical


@pytest.fixture
def installed() -> Iterator[None]:
    old_int, old_term = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    INTERRUPTS.install()
    try:
        yield
    finally:
        INTERRUPTS.reset()
        signal.signal(signal.SIGINT, old_int)
        signal.signal(signal.SIGTERM, old_term)


def test_interrupt_inside_critical_is_held_until_the_write_ends(installed: None) -> None:
    written = []
    with pytest.raises(KeyboardInterrupt), critical():
        os.kill(os.getpid(), signal.SIGINT)
        written.append("first half")
        written.append("second half")  # the write completes before the interrupt
    assert written == ["first half", "second half"]


def test_interrupt_outside_critical_is_immediate(installed: None) -> None:
    reached = False
    with pytest.raises(KeyboardInterrupt):
        os.kill(os.getpid(), signal.SIGINT)
        reached = True
    assert not reached
