"""aia.runtime.stopping: a signal is recorded (the first one) and reported to ``on_signal``; the previous
handlers come back on exit; under ``interrupting`` a signal raises ``Stopped`` unless a loop's handlers are in."""

from __future__ import annotations

import os
import signal

import pytest

from aia.config.errors import Stopped
from aia.runtime.stopping import StopOnSignals, interrupting


def _send(signum: int) -> None:
    """Deliver ``signum`` to this process now (Python runs the handler before the next line)."""
    os.kill(os.getpid(), signum)


def test_the_first_signal_is_kept_and_every_signal_is_reported():
    calls = []
    before = signal.getsignal(signal.SIGUSR1)
    with StopOnSignals(on_signal=lambda signum, first: calls.append((signum, first))) as stop:
        assert stop.signal is None
        _send(signal.SIGUSR1)
        _send(signal.SIGTERM)
        assert stop.signal == signal.SIGUSR1 and stop.exit_status == 128 + signal.SIGUSR1
    assert calls == [(signal.SIGUSR1, True), (signal.SIGTERM, False)]
    assert signal.getsignal(signal.SIGUSR1) is before


def test_interrupting_raises_at_once_unless_an_inner_stop_takes_the_signals_over():
    before = signal.getsignal(signal.SIGUSR1)
    with pytest.raises(Stopped) as raised, interrupting():
        with StopOnSignals() as loop:
            _send(signal.SIGTERM)  # the loop's: recorded, not raised
        assert loop.signal == signal.SIGTERM
        _send(signal.SIGUSR1)
    assert raised.value.signum == signal.SIGUSR1 and raised.value.exit_status == 128 + signal.SIGUSR1
    assert str(raised.value) == "SIGUSR1"
    assert signal.getsignal(signal.SIGUSR1) is before
