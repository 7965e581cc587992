"""poise command-line interface (click). A thin adapter over :mod:`poise.api`.

Every module here imports only ``click`` and the standard library at import time so that
``poise --help`` stays fast; numpy/h5py/the solver are imported inside command functions.
"""
