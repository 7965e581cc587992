"""The suite holds whatever it inherits: variables that change what poise (or Dask, or click)
prints are removed for the whole session, before any test or fixture runs (subprocesses inherit
the cleaned environment). Signal dispositions are not touched here: a test that starts poise to
interrupt it resets SIGINT in the child itself (``preexec_fn``), since a background job of a
script starts with SIGINT ignored and ``nohup`` with SIGHUP ignored.

Fixtures every test group may use (their code lives in ``tests/support``): ``runner``."""
from __future__ import annotations

import os

import pytest

#: read by poise (quiet progress, full interpreter exit, the memory budget, colours) and by
#: click (terminal size); DASK_* configures Dask
_INHERITED = ("POISE_QUIET", "POISE_FULL_EXIT", "POISE_MAX_MEMORY", "NO_COLOR", "COLUMNS",
              "LINES")


def pytest_configure(config):
    for name in list(os.environ):
        if name in _INHERITED or name.startswith("DASK_"):
            del os.environ[name]


@pytest.fixture
def runner(tmp_path):
    """Solve a :class:`poise.gen.deck.Deck` in-process (``api``) or by ``poise solve`` (``cli``)."""
    from support.runner import Runner      # after pytest_configure cleaned the environment
    return Runner(tmp_path)
