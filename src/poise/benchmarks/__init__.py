"""Benchmarks of issue 7: work-precision ladders, a peer (Exudyn) side by side, and scaling.

Run through ``make bench`` (``python -m poise.bench`` calls :func:`poise.benchmarks.main.run`
after the chain benchmark and appends its sections to docs/performance.md) or on its own::

    python -m poise.benchmarks [--quick] [--out bench/wp.jsonl] [--markdown PART.md]

Modules: :mod:`.decks` (benchmark decks, grid generator, tolerance variants), :mod:`.wp`
(tolerance ladders and errors against independent references), :mod:`.peer` (Exudyn),
:mod:`.scaling` (chains and grids vs N), :mod:`.report` (markdown + matplotlib plots).
"""
