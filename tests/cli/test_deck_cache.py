"""Repeated in-process solves reuse the parsed deck and compiled model only while the file is
unchanged (poise.app.deck_cache): an edit, even one that keeps size and modification time,
is solved from the new content."""
from __future__ import annotations

import os
import shutil

import numpy as np

import poise
from poise.app import deck_cache

from support.paths import DECKS


def test_same_file_reuses_model_and_edit_is_seen(tmp_path):
    deck = tmp_path / "pend.xml"
    shutil.copy(DECKS / "pendulum_multiturn.xml", deck)
    deck_cache.clear()
    a = poise.solve(str(deck), quiet=True)
    key = (str(deck), os.path.abspath(str(deck)))
    assert key in deck_cache._entries and deck_cache._entries[key].models
    model = deck_cache._entries[key].models["refuse"]
    b = poise.solve(str(deck), quiet=True)
    assert deck_cache._entries[key].models["refuse"] is model          # reused
    pa = a.analyses[0].datasets["bodies/position"]
    pb = b.analyses[0].datasets["bodies/position"]
    assert np.array_equal(pa, pb)
    # a different stiffness of the same length, size and modification time: solved anew
    st = os.stat(deck)
    text = deck.read_text()
    assert 'stiffness="20000.0"' in text
    deck.write_text(text.replace('stiffness="20000.0"', 'stiffness="30000.0"'))
    os.utime(deck, ns=(st.st_atime_ns, st.st_mtime_ns))
    assert os.stat(deck).st_size == st.st_size
    c = poise.solve(str(deck), quiet=True)
    assert deck_cache._entries[key].models["refuse"] is not model
    pc = c.analyses[0].datasets["bodies/position"]
    assert not np.allclose(pa, pc)
    # a fresh process-level solve of the edited deck (no cache) agrees with the cached one
    deck_cache.clear()
    d = poise.solve(str(deck), quiet=True)
    assert np.array_equal(pc, d.analyses[0].datasets["bodies/position"])


def test_spec_copies_are_independent(tmp_path):
    deck = tmp_path / "pend.xml"
    shutil.copy(DECKS / "pendulum_multiturn.xml", deck)
    deck_cache.clear()
    from poise.deck.parser import load_deck
    s1 = deck_cache.load(str(deck), (), lambda p, i: load_deck(p))
    s1.model.clear()
    s2 = deck_cache.load(str(deck), (), lambda p, i: load_deck(p))
    assert s2.model and s2 is not s1


def test_large_or_dataset_decks_are_not_kept(tmp_path):
    deck_cache.clear()
    big = tmp_path / "big.xml"
    big.write_bytes(b"<!--" + b"x" * (deck_cache.MAX_BYTES + 10) + b"-->")
    assert deck_cache._key_stamp(str(big)) is None
    assert deck_cache._key_stamp(str(tmp_path / "m.adm")) is None
    assert deck_cache._key_stamp(str(tmp_path / "missing.xml")) is None
