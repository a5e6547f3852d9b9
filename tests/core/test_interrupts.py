"""sonarsim.core.interrupts: Ctrl-C held back during a block, delivered at its end."""

from __future__ import annotations

import os
import signal

import pytest

from sonarsim.core.interrupts import signals_deferred


def test_ctrl_c_inside_the_block_is_delivered_at_its_end():
    reached_end_of_block = False
    with pytest.raises(KeyboardInterrupt):
        with signals_deferred():
            os.kill(os.getpid(), signal.SIGINT)
            try:  # a library that swallows everything, as trimesh's optional imports do
                sum(range(10_000))
            except BaseException:  # noqa: BLE001
                pytest.fail("the signal reached the block")
            reached_end_of_block = True
    assert reached_end_of_block
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_the_previous_handlers_get_each_signal_once_and_are_restored():
    seen = []

    def record(signum, frame):
        seen.append(signum)

    before = signal.signal(signal.SIGTERM, record)
    try:
        with signals_deferred():
            os.kill(os.getpid(), signal.SIGTERM)
            os.kill(os.getpid(), signal.SIGTERM)
            assert seen == []
        assert seen == [signal.SIGTERM]
        assert signal.getsignal(signal.SIGTERM) is record
    finally:
        signal.signal(signal.SIGTERM, before)


def test_nothing_pending_changes_nothing():
    with signals_deferred():
        pass
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
