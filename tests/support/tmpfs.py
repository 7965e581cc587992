"""A real full or read-only filesystem for I/O failure tests: a small tmpfs (root only)."""
from __future__ import annotations

import contextlib
import os
import subprocess

import pytest


@contextlib.contextmanager
def tmpfs(mnt, options: str):
    """Mount a tmpfs with ``options`` (``size=64k``, ``ro,size=64k``) at the new directory
    ``mnt`` (root only; else the test is skipped), yield it, unmount it."""
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    mnt.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(mnt)],
                      capture_output=True).returncode != 0:
        pytest.skip("cannot mount a tmpfs here")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", str(mnt)], capture_output=True)
