"""Orchestration: run a deck's analyses (runner), check a deck, batches, sweeps, the public API
(api) and the tolerance ladder of ``poise bench``. Imports every layer below; nothing imports it
except the package root (lazily) and the command line."""
