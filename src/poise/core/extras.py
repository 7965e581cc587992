"""Optional extras: matplotlib (``poise[plot]``) and Dask (``poise[sweep]``).

``pip install poise`` is a lean solver; pictures and Dask runs need an extra. A feature that
needs one calls :func:`require` first: without the package it raises :class:`MissingExtra`, a
usage error (exit 2) whose message is the pip command to run, instead of an ImportError
traceback from deep inside the feature.
"""
from __future__ import annotations

from poise.core.errors import UsageError

#: extra name -> (modules it provides, what needs it)
EXTRAS = {
    "plot": (("matplotlib",), "pictures (poise plot, poise animate, poise bench --plot)"),
    "sweep": (("dask", "distributed"), "Dask runs (poise sweep, poise batch --scheduler)"),
}


class MissingExtra(UsageError):
    """A feature's optional dependency is not installed (exit 2, says what to install)."""


def available(extra: str) -> bool:
    """Whether every module of ``extra`` can be imported (imports them)."""
    import importlib
    for mod in EXTRAS[extra][0]:
        try:
            importlib.import_module(mod)
        except ImportError:
            return False
    return True


def require(extra: str, feature: str | None = None) -> None:
    """Raise :class:`MissingExtra` naming the pip command when ``extra`` is not installed."""
    if available(extra):
        return
    mods, what = EXTRAS[extra]
    raise MissingExtra(f"{feature or what} needs {' and '.join(mods)}, which "
                       f"{'is' if len(mods) == 1 else 'are'} not installed; run: "
                       f"pip install 'poise[{extra}]'  (or 'poise[all]')")
