"""Ctrl-C (SIGINT) and SIGTERM held off while work must not stop half way: a frame half processed, a
log record half written. A held signal reaches the handler it would have met at a ``checkpoint`` or
when the block ends; with Python's defaults that raises ``KeyboardInterrupt`` there, in plain Python
code, never inside a call into OpenCV, gtsam or the MCAP writer. Long work inside a frame calls the
module's ``checkpoint()`` between its steps (MagicWarp's iterations, the odometry's stages), so that a
signal takes effect within one step, not at the end of the frame."""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

HELD = (signal.SIGINT, signal.SIGTERM)
_ACTIVE: list[HeldSignals] = []  # the blocks in force, innermost last


@dataclass
class HeldSignals:
    """The handlers in place before the block (by signal number) and the signals received since."""

    previous: dict[int, object] = field(default_factory=dict)
    received: list[int] = field(default_factory=list)

    def checkpoint(self) -> None:
        """Deliver a signal received so far (repeats count once) to the handler it would have met."""
        if not self.received:
            return
        number = self.received[0]
        self.received.clear()
        handler = self.previous[number]
        if callable(handler):
            handler(number, None)
        elif handler == signal.SIG_DFL:  # the default action (end the process), as without the block
            self._restore()
            signal.raise_signal(number)

    def _restore(self) -> None:
        for number, handler in self.previous.items():
            if handler is not None:  # None: a handler installed from C, which Python cannot put back
                signal.signal(number, handler)


@contextmanager
def held_signals() -> Iterator[HeldSignals]:
    """``with held_signals() as held: ... held.checkpoint() ...``: SIGINT and SIGTERM wait for a checkpoint
    or the end of the block. Only the main thread can handle signals; elsewhere nothing is held."""
    held = HeldSignals()
    if threading.current_thread() is not threading.main_thread():
        yield held
        return
    held.previous = {number: signal.signal(number, lambda n, _: held.received.append(n)) for number in HELD}
    _ACTIVE.append(held)
    try:
        yield held
    finally:
        _ACTIVE.remove(held)
        held._restore()
        held.checkpoint()


def checkpoint() -> None:
    """Deliver a signal the innermost ``held_signals`` block received (nothing outside one): for work that
    may stop between its steps."""
    if _ACTIVE:
        _ACTIVE[-1].checkpoint()


def import_pycolmap():
    """pycolmap, imported so that SIGTERM still reaches Python's handler. Importing it installs glog's failure
    handler for SIGTERM from C, which ends the process at once (a log in progress left unfinished) while
    ``signal.getsignal`` still names Python's handler; that handler is installed again here (from the main thread
    only, where Python handles signals). A SIGTERM during the import itself meets glog's: the commands that run
    the pipeline import pycolmap before they open a log or handle SIGTERM (``cli.main``)."""
    import pycolmap

    if threading.current_thread() is threading.main_thread():
        handler = signal.getsignal(signal.SIGTERM)
        if handler is not None:  # None: a handler installed from C before Python's, nothing to put back
            signal.signal(signal.SIGTERM, handler)
    return pycolmap
