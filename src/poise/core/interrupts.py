"""Ctrl-C and SIGTERM that code poise calls cannot swallow.

A user routine runs inside ``except BaseException`` (anything it raises fails the solve
cleanly), so a ``KeyboardInterrupt`` raised by a signal while it runs would become "user
function raised KeyboardInterrupt", or be caught by the routine itself, and the run would go on.
:data:`kept_interrupts` relays SIGINT/SIGTERM to the handler already installed (main thread
only, and only where that handler is Python code: an ignored or default disposition is left
alone), remembers what the handler raised, and raises it again when the block ends, whatever
the code inside did with it. Nested blocks share the outermost one's relay.
"""
from __future__ import annotations

import signal
import threading

_SIGNALS = (signal.SIGINT, signal.SIGTERM)


class _KeptInterrupts:
    """Context manager (reentrant, one instance): see the module doc."""

    def __init__(self):
        self._depth = 0
        self._old: dict = {}
        self._raised: list[BaseException] = []

    def __enter__(self):
        if threading.current_thread() is not threading.main_thread():
            return self
        self._depth += 1
        if self._depth == 1:
            self._raised.clear()
            for sig in _SIGNALS:
                handler = signal.getsignal(sig)
                if callable(handler):
                    self._old[sig] = handler
                    signal.signal(sig, self._relay)
        return self

    def _relay(self, signum, frame):
        try:
            self._old[signum](signum, frame)
        except BaseException as e:  # noqa: BLE001 - recorded, then raised on
            self._raised.append(e)
            raise

    def __exit__(self, *exc):
        if threading.current_thread() is not threading.main_thread():
            return False
        self._depth -= 1
        if self._depth:
            return False
        for sig, handler in self._old.items():
            signal.signal(sig, handler)
        self._old.clear()
        if self._raised:
            e = self._raised[0]
            self._raised.clear()
            raise e
        return False


def kept_interrupts() -> _KeptInterrupts:
    """``with kept_interrupts(): ...`` re-raises at the end of the block what a SIGINT/SIGTERM
    handler raised inside it."""
    return _KEPT


_KEPT = _KeptInterrupts()
