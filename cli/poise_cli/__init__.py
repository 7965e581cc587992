"""poise command-line interface (click). A thin adapter over :mod:`poise.app.api`.

Every module here imports only ``click`` and the standard library at import time so that
``poise --help`` stays fast; numpy/h5py/the solver are imported inside command functions.
"""

import os as _os
import _signal  # the C module: ``signal`` imports enum, a window for an import traceback
import sys as _sys


#: set by the command's Ctrl-C/SIGTERM handlers (:mod:`poise_cli.main`) before they raise
#: KeyboardInterrupt: code that turns that exception into another one (Cython's ImportError when
#: the signal lands inside an import) cannot hide that the user interrupted the command
signalled = False


def _early_interrupt(signum, frame):  # pragma: no cover - timing dependent
    """Ctrl-C/SIGTERM while the command line interface is still starting (imports): one line,
    exit 130 (a KeyboardInterrupt here would print an import traceback)."""
    mp = _sys.modules.get("multiprocessing")
    if mp is None or mp.parent_process() is None:   # a batch worker leaves it to the parent
        _os.write(2, b"poise: interrupted\n")
    _os._exit(130)


def _install_early_handlers() -> None:
    """Only in the ``poise`` console script (not in a library or test process importing us);
    :meth:`poise_cli.main.LazyGroup.invoke` replaces these once a command runs."""
    if _os.path.basename(_sys.argv[0] if _sys.argv else "") != "poise":
        return
    try:
        if _signal.getsignal(_signal.SIGINT) is _signal.default_int_handler:
            _signal.signal(_signal.SIGINT, _early_interrupt)
        if _signal.getsignal(_signal.SIGTERM) == _signal.SIG_DFL:
            _signal.signal(_signal.SIGTERM, _early_interrupt)
    except (ValueError, OSError):  # not the main thread
        pass


_install_early_handlers()
