"""Optional extras: matplotlib (``poise[plot]``), Dask (``poise[sweep]``) and the labelled
arrays of xarray / pandas (``poise[xarray]``).

``pip install poise`` is a lean solver; pictures, Dask runs and labelled arrays need an extra.
A feature that needs one calls :func:`require` first: without the package it raises
:class:`MissingExtra`, a usage error (exit 2) and an ``ImportError`` whose message is the pip
command to run, instead of an ImportError traceback from deep inside the feature.
"""
from __future__ import annotations

from poise.core.errors import UsageError

#: extra name -> (modules it provides, what needs it)
EXTRAS = {
    "plot": (("matplotlib",), "pictures (poise plot, poise animate, poise bench --plot)"),
    "sweep": (("dask", "distributed"), "Dask runs (poise sweep, poise batch --scheduler)"),
    "xarray": (("xarray", "h5netcdf", "pandas"), "labelled arrays (RunResult.to_xarray, "
               "to_dataframe)"),
}


class MissingExtra(UsageError, ImportError):
    """A feature's optional dependency is not installed (exit 2, says what to install; an
    ``ImportError`` for library callers)."""


def available(extra: str) -> bool:
    """Whether every module of ``extra`` can be imported (imports them)."""
    return all(_importable(mod) for mod in EXTRAS[extra][0])


def require(extra: str, feature: str | None = None) -> None:
    """Raise :class:`MissingExtra` naming the pip command when ``extra`` is not installed."""
    if available(extra):
        return
    mods, what = EXTRAS[extra]
    missing = [m for m in mods if not _importable(m)] or list(mods)
    raise MissingExtra(f"{feature or what} needs {' and '.join(missing)}, which "
                       f"{'is' if len(missing) == 1 else 'are'} not installed; run: "
                       f"pip install 'poise[{extra}]'  (or 'poise[all]')")


def _importable(mod: str) -> bool:
    import importlib
    try:
        importlib.import_module(mod)
    except ImportError:
        return False
    return True
