"""Corrupt and hostile results files (made by the reliability study's make_corrupt_results.py:
bit flips, a float ``stability``, a scalar / 2-D / null ``time``, string body ids, links to
other files, a virtual dataset, a dataset declaring 745 GiB, settings that are not JSON, ...)
give ``poise show``, ``plot`` and ``animate`` exit 2 with ``not a usable poise results file:
<dataset>: ...`` before any data is read, or a correct summary / picture: never exit 4, a
traceback, a MemoryError or a file read through a link."""
from __future__ import annotations

import subprocess
import sys

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

from poise.results.hdf5 import ResultsFormatError, read_results
from poise_cli.main import cli

from support.paths import DATA, ROOT

SCRIPT = DATA / "reliability" / "decks" / "make_corrupt_results.py"
#: file -> the dataset its message names (exit 2 for every command)
REFUSED = {
    "stability_as_float": "/analysis_000/frames/stability: dtype float64, declared str",
    "time_scalar": "/analysis_000/time: shape (), declared (F,)",
    "time_2d": "/analysis_000/time: shape (2, 2), declared (F,)",
    "time_null_dataspace": "/analysis_000/time: no data (a null dataspace)",
    "bodies_id_string": "/analysis_000/bodies/id: dtype |S1, declared int",
    "external_link_missing": "/analysis_000/bodies: a link to another file",
    "external_link_etc_passwd": "/model: a link to another file (/etc/passwd:/x)",
    "virtual_dataset_missing_source": "/analysis_000/frames/imbalance: a virtual dataset",
    "huge_declared_dataset": "/analysis_000/frames/imbalance: declares 745 GiB of data (shape "
                             "(100000000000,)",
    "settings_not_json": "/analysis_000@settings: not a JSON object",
    "position_2d": "/analysis_000/bodies/position: shape (21, 9), declared (F, B, 3)",
    "mkeam_no_bodies": "/analysis_000: no dataset 'bodies/position'",
}


@pytest.fixture(scope="module")
def corrupt(tmp_path_factory):
    pytest.importorskip("matplotlib")
    out = tmp_path_factory.mktemp("corrupt")
    p = subprocess.run([sys.executable, str(SCRIPT), str(out)], cwd=ROOT, capture_output=True,
                       text=True, timeout=600)
    assert p.returncode == 0, p.stderr
    return out


def _commands(path, tmp_path):
    return {"show": ["show", str(path)],
            "plot": ["plot", str(path), "--out", str(tmp_path / "p.png")],
            "animate": ["animate", str(path), "--out", str(tmp_path / "a.gif"),
                        "--max-frames", "3"]}


@pytest.mark.parametrize("name", sorted(REFUSED))
def test_refused_naming_the_dataset(corrupt, tmp_path, name):
    path = corrupt / f"{name}.h5"
    for cmd, args in _commands(path, tmp_path).items():
        r = CliRunner().invoke(cli, args)
        assert r.exit_code == 2, (cmd, r.output)
        line = r.stderr.strip().splitlines()[-1]
        assert line.startswith(f"poise: error: {path}: not a usable poise results file: "), line
        assert REFUSED[name] in line, (cmd, line)
    assert list(tmp_path.iterdir()) == []          # no picture, no temporary file
    with pytest.raises(ResultsFormatError, match="not a usable poise results file"):
        read_results(str(path))


def test_bit_flips_are_refused_or_read_cleanly(corrupt, tmp_path):
    """Flipped bytes of a valid file (the study's seed and a few more): exit 0 (the flips hit
    data) or exit 2 naming what HDF5 could not read, never another outcome."""
    base = (corrupt / "_qs.h5").read_bytes()
    files = [corrupt / "bitflips.h5"]
    for seed in range(2, 8):
        b = bytearray(base)
        rng = np.random.default_rng(seed)
        for i in rng.integers(len(b) // 4, len(b), 200):
            b[i] ^= 0xFF
        files.append(tmp_path / f"flips{seed}.h5")
        files[-1].write_bytes(bytes(b))
    pics = tmp_path / "pics"
    pics.mkdir()
    for path in files:
        for cmd, args in _commands(path, pics).items():
            r = CliRunner().invoke(cli, args)
            assert r.exit_code in (0, 2), (path.name, cmd, r.output)
            if r.exit_code == 2:
                assert "not a usable poise results file" in r.stderr or "not an HDF5 file" in \
                    r.stderr or "not a poise results file" in r.stderr, r.stderr


def test_non_finite_positions_draw_what_is_finite(corrupt, tmp_path):
    """position_nan_inf.h5: x of every body NaN, the last frame -inf: the animation draws the
    finite points (ground), the plot and the summary read the file."""
    path = corrupt / "position_nan_inf.h5"
    for cmd, args in _commands(path, tmp_path).items():
        r = CliRunner().invoke(cli, args)
        assert r.exit_code == 0, (cmd, r.output)
    assert (tmp_path / "p.png").stat().st_size > 0 and (tmp_path / "a.gif").stat().st_size > 0


def test_valid_files_still_read(corrupt):
    for name in ("_static", "_qs", "_mkeam"):
        res = read_results(str(corrupt / f"{name}.h5"))
        with h5py.File(corrupt / f"{name}.h5") as f:
            np.testing.assert_array_equal(res.analyses[0].datasets["bodies/position"],
                                          f["analysis_000/bodies/position"][()])
