"""Big decks scale linearly: Python-level call counts, no timing.

Parse (secure lxml walk + collect-all validation), compile and a static solve of a 200- and a
2000-link hanging chain run under cProfile. Two properties are checked:

* no function is called more than linearly more often for 10x the links (a per-element re-scan
  of the deck, a quadratic lookup or a per-pair loop shows up as a ~100x growth);
* the Python-level calls per additional link stay a small constant (the column-wise typing,
  validation screen, batched compile and vectorised kernels stay column-wise; a silent fallback
  to an element-by-element path roughly doubles them).

Both sizes converge in the same number of Newton iterations, so per-iteration work cancels.
"""
from __future__ import annotations

import cProfile
import gc

import pytest

from poise.app import runner
from poise.deck.parser import parse_deck_bytes
from poise.gen.chain import build_chain_deck

N1, N2 = 200, 2000
# Python-level calls (functions and builtins) per additional link for parse + compile + solve
# (5 deck elements, 5 constraint rows per link): measured 287, against 1750 for the element-by-
# element reader and compiler this replaced; the budget leaves room for small changes, not for
# an element-by-element path. Solving an in-memory DeckSpec validates it again (an edited spec is
# checked exactly like the file): ~80 more calls per link, measured 437; the Adams reader's
# locations, the declared-attribute check and the netCDF view took it to 466 alone and 484 after
# other tests of a full run (caches warmed differently; counted per code object and with
# scipy.optimize imported first, as the fixture does, 489 whatever ran before). The budget keeps
# ~15 % of headroom over that, far below the ~1750 of an element-by-element path.
CALLS_PER_LINK = 560


def _run(n: int):
    data = build_chain_deck(n).encode()
    prof = cProfile.Profile()
    prof.enable()
    spec = parse_deck_bytes(data, f"chain_{n}.xml")
    res = runner.run(spec)
    prof.disable()
    assert res.analyses[0].status == "converged"
    # callbacks the garbage collector runs (hypothesis registers one when a property test ran
    # earlier in the session) follow the collector's thresholds, not poise's calls
    gc_cbs = {(c.__code__.co_filename, c.__code__.co_firstlineno, c.__code__.co_name)
              for c in gc.callbacks if hasattr(c, "__code__")}
    # per code object, summed by name: pstats keeps one of the functions that share a key
    # (every dataclass's generated ``<string>:2(__init__)``), which one depending on what else
    # the session compiled
    calls: dict = {}
    for e in prof.getstats():
        c = e.code
        key = ((c.co_filename, c.co_firstlineno, c.co_name) if hasattr(c, "co_filename")
               else ("~", 0, str(c)))
        if key not in gc_cbs:
            calls[key] = calls.get(key, 0) + e.callcount
    return calls, res.counts


@pytest.fixture(scope="module")
def profiles():
    import scipy.optimize  # noqa: F401  the same count whatever ran before (see CALLS_PER_LINK)
    _run(50)                                   # imports and one-time caches out of the way
    return _run(N1), _run(N2)


def _name(key) -> str:
    file, line, func = key
    return f"{file.rsplit('/', 1)[-1]}:{line}({func})"


def test_same_iterations_both_sizes(profiles):
    (_, c1), (_, c2) = profiles
    assert c1["jacobians"] == c2["jacobians"] and c1["factorizations"] == c2["factorizations"]
    # one more residual (a line-search trial at the round-off floor) is per-iteration noise
    assert abs(c1["residuals"] - c2["residuals"]) <= 1, (c1, c2)


def test_no_function_grows_faster_than_linearly(profiles):
    (a, _), (b, _) = profiles
    ratio = N2 / N1
    bad = {_name(k): (a.get(k, 0), n) for k, n in b.items()
           if n > 1.2 * ratio * a.get(k, 0) + 100}
    assert not bad, f"calls at {N1} and {N2} links (superlinear): {bad}"


def test_python_calls_per_link_are_a_small_constant(profiles):
    (a, _), (b, _) = profiles
    per_link = (sum(b.values()) - sum(a.values())) / (N2 - N1)
    top = sorted(((b[k] - a.get(k, 0), _name(k)) for k in b), reverse=True)[:8]
    assert per_link <= CALLS_PER_LINK, f"{per_link:.0f} calls per link; largest: {top}"
