"""Fixtures every test group may use (their code lives in ``tests/support``)."""
import pytest

from support.runner import Runner


@pytest.fixture
def runner(tmp_path):
    """Solve a :class:`poise.gen.deck.Deck` in-process (``api``) or by ``poise solve`` (``cli``)."""
    return Runner(tmp_path)
