"""The levitated ball's data: the shipped copies, the three formats, bad input."""
from pathlib import Path

import numpy as np
import pytest

from ssamb.io import DataError
from ssamb.maglev1d.data import (COLUMNS, load_data, levitated_mask, levitated_stretches, sha256_of,
                                 validate_arrays)

ROOT = Path(__file__).resolve().parent.parent
SHIPPED = sorted((ROOT / "resources" / "maglev1d").glob("dataset_*.npz"))
Q_Y = 0.05 / 1023.0
Q_I = 5.0 / (2.2 * 1023.0)


def test_five_recordings_shipped_small():
    assert len(SHIPPED) == 5
    assert sum(p.stat().st_size for p in SHIPPED) < 300_000


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: p.stem.split("_")[1])
def test_shipped_copy_is_the_logged_data(path):
    arrays, meta = load_data(path)
    assert set(arrays) == set(COLUMNS)
    assert meta["source_commit"] == "2302eb0da3fd31f5c8ab6ac7a37b44792e1d57bf"
    validate_arrays(arrays, str(path), 0.01)
    # the logged position and current are ADC counts, written with 6 and 4 decimals
    assert np.max(np.abs(arrays["y"] - Q_Y * np.round(arrays["y"] / Q_Y))) <= 0.5e-6 + 1e-12
    assert np.max(np.abs(arrays["i"] - Q_I * np.round(arrays["i"] / Q_I))) <= 0.5e-4 + 1e-12


def _rig_log(tmp_path, rows, columns="t y y_obs dy_obs i u yd"):
    p = tmp_path / "log.txt"
    text = "# Dataset Levitador Magn\xe9tico\n# Columnas: " + columns + "\n#\n" + "".join(rows)
    p.write_bytes(text.encode("latin-1"))
    return p


def _row(k, y=0.005, i=0.45, u=7.0, yd=0.005):
    return f"{k * 0.01:.4f}\t{y:.6f}\t0.005\t0.0\t{i:.4f}\t{u:.4f}\t{yd:.6f}\n"


def test_rig_log_read_by_header_names(tmp_path):
    p = _rig_log(tmp_path, [_row(k, y=0.004 + 1e-6 * k) for k in range(20)])
    arrays, meta = load_data(p)
    assert meta["format"] == "rig_log"
    np.testing.assert_allclose(arrays["y"][:3], [0.004, 0.004001, 0.004002])
    np.testing.assert_allclose(arrays["t"][-1], 0.19)


def test_csv_extra_columns_ignored(tmp_path):
    p = tmp_path / "d.csv"
    p.write_text("t,extra,y,i,u,yd\n" + "".join(f"{k * 0.01},1,0.005,0.45,7,0.005\n" for k in range(20)))
    arrays, meta = load_data(p)
    assert meta["format"] == "csv" and set(arrays) == set(COLUMNS)


@pytest.mark.parametrize("case, word", [
    ("missing", "'yd'"), ("text", "'i'"), ("empty", "empty"), ("header_only", "no data"),
])
def test_bad_files_name_file_and_column(tmp_path, case, word):
    p = tmp_path / "d.csv"
    if case == "missing":
        p.write_text("t,y,i,u\n0,0.005,0.4,7\n")
    elif case == "text":
        p.write_text("t,y,i,u,yd\n0,0.005,0.4,7,0.005\n0.01,0.005,abc,7,0.005\n")
    elif case == "empty":
        p.write_text("")
    else:
        p.write_text("t,y,i,u,yd\n")
    with pytest.raises(DataError) as exc:
        load_data(p)
    msg = str(exc.value)
    assert str(p) in msg and word in msg and "\n" not in msg


def test_rig_log_text_cell(tmp_path):
    rows = [_row(k) for k in range(5)]
    rows[3] = rows[3].replace("0.4500", "0.4x00")
    with pytest.raises(DataError, match=r"column 'i', line 7"):
        load_data(_rig_log(tmp_path, rows))


def test_rig_log_missing_column(tmp_path):
    with pytest.raises(DataError, match="column 'yd' missing"):
        load_data(_rig_log(tmp_path, [_row(0)[:-10] + "\n"], columns="t y y_obs dy_obs i u"))


@pytest.mark.parametrize("col", ["y", "u"])
def test_nonfinite_named(col):
    a = {c: np.full(50, 0.005) for c in COLUMNS}
    a["t"] = np.arange(50) * 0.01
    a[col][7] = np.nan
    with pytest.raises(DataError, match=f"column '{col}' has 1 non-finite"):
        validate_arrays(a, "f.csv", 0.01)


def test_nonuniform_time_named():
    a = {c: np.full(50, 0.005) for c in COLUMNS}
    a["t"] = np.arange(50) * 0.01
    a["t"][20:] += 0.004
    with pytest.raises(DataError, match=r"f.csv: column 't' is not a uniform time base .*sample 20 is"):
        validate_arrays(a, "f.csv", 0.01)


def test_levitated_stretches_need_current_and_distance_from_stops():
    y = np.r_[np.full(10, 0.0), np.full(30, 0.005), np.full(10, 0.0195), np.full(30, 0.005)]
    i = np.r_[np.zeros(10), np.full(30, 0.45), np.full(10, 0.78), np.full(15, 0.02), np.full(15, 0.45)]
    m = levitated_mask(y, i, 0.0, 0.0195, 0.001, 0.1)
    assert levitated_stretches(m, 10) == [(10, 40), (65, 80)]
    assert levitated_stretches(m, 20) == [(10, 40)]


def test_sha256(tmp_path):
    p = tmp_path / "x"
    p.write_bytes(b"abc")
    assert sha256_of(p) == "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"


def test_time_written_to_a_tenth_of_a_millisecond_is_uniform():
    """The acquisition program writes an accumulated t += Ts with four decimals: steps of 0.0099
    and 0.0101 s are the same period; a dropped sample is not."""
    a = {c: np.full(2000, 0.005) for c in COLUMNS}
    t = np.cumsum(np.full(2000, np.float32(0.01)), dtype=np.float32).astype(float)
    a["t"] = np.round(t, 4)
    assert np.any(np.abs(np.diff(a["t"]) - 0.01) > 1e-5)
    validate_arrays(a, "f.csv", 0.01)
    a["t"] = np.r_[a["t"][:200], a["t"][201:], a["t"][-1] + 0.01]
    with pytest.raises(DataError, match="sample 200 is 0.02"):
        validate_arrays(a, "f.csv", 0.01)
