"""poise's benchmarks (``make bench`` / ``make bench-quick``: ``python -m benchmarks`` from the
repository root); not part of the installed package.

Modules: :mod:`.chain` (hanging chains, command-line start-up), :mod:`.expr` (10 000 expression
forces), :mod:`.suite` (work-precision, peer and scaling suites), :mod:`.decks` (benchmark
decks, grid generator), :mod:`.wp` (tolerance ladders and errors against independent
references), :mod:`.peer` (Exudyn), :mod:`.scaling` (chains and grids vs N), :mod:`.stable`
(stable equilibria), :mod:`.report` (markdown + matplotlib plots).
"""
