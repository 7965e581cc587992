"""Paths every test shares, defined once here so that a test file can move between the
directories of ``tests/`` without any path arithmetic of its own."""
from pathlib import Path

TESTS = Path(__file__).resolve().parents[1]     # tests/
ROOT = TESTS.parent                             # the repository
DECKS = ROOT / "decks"                          # the example decks
DATA = TESTS / "data"                           # test inputs that are not example decks
