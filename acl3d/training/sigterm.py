"""SIGTERM ends a run (or a campaign) like Ctrl-C: batch schedulers stop jobs with it, and a
campaign's attempt gets it when its campaign process dies. The run's handler of the interruption
then writes its status ("interrupted", the latest checkpoint); the SIGTERMs that follow the first
are ignored until the block is left, so a second one cannot cut that write short and leave
"running".
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager


@contextmanager
def sigterm_interrupts() -> Iterator[None]:
    """Within the block, the first SIGTERM raises KeyboardInterrupt and later ones are ignored;
    the previous handler is back afterwards. Off the main thread (where Python cannot set
    handlers) the block runs unchanged."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, _interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _interrupt(signum, frame):
    signal.signal(signal.SIGTERM, signal.SIG_IGN)  # the interruption is handled once, whole
    raise KeyboardInterrupt(f"signal {signum}")
