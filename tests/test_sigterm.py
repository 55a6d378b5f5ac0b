"""SIGTERM ends a run like Ctrl-C, once: a second SIGTERM while the run writes its status does
not cut that write short (a campaign's attempt once stayed "running" that way)."""

from __future__ import annotations

import os
import signal
import threading

import pytest

from acl3d.training.sigterm import sigterm_interrupts


def _terminate_self() -> None:
    os.kill(os.getpid(), signal.SIGTERM)


def test_the_first_sigterm_interrupts_and_later_ones_wait_for_the_handler():
    before = signal.getsignal(signal.SIGTERM)
    written = []
    with pytest.raises(KeyboardInterrupt, match="signal 15"):
        with sigterm_interrupts():
            try:
                _terminate_self()
                pytest.fail("SIGTERM did not interrupt")
            except KeyboardInterrupt:
                _terminate_self()  # a second signal while the status is written
                written.append("interrupted")
                raise
    assert written == ["interrupted"]
    assert signal.getsignal(signal.SIGTERM) is before


def test_a_block_off_the_main_thread_runs_unchanged():
    seen = []

    def worker():
        with sigterm_interrupts():
            seen.append(signal.getsignal(signal.SIGTERM))

    before = signal.getsignal(signal.SIGTERM)
    thread = threading.Thread(target=worker)
    thread.start()
    thread.join()
    assert seen == [before]
