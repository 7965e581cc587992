"""The base layer: errors with deck locations, atomic output files, phase timers, the version,
the loader of Python user routines. Imports nothing above it."""
