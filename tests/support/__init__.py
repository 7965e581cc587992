"""Helpers shared by the test files (not tests): paths, deck builders, independent references,
finite-difference checks, expression fakes and a synthetic results file. ``tests/`` is on
``sys.path`` (pyproject ``pythonpath``), so a test imports them as ``from support.X import Y``
from any directory."""
