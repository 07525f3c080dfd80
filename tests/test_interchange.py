"""The interchange CSV: round trip, dropouts, and errors that name line and column."""

from __future__ import annotations

import numpy as np
import pytest

from gateway.errors import CsvFormatError
from gateway.offline.interchange import read_csv, write_csv

HEADER = "time_s,bogie_lat_acc_mps2,bogie_yaw_rate_radps,body_lat_acc_mps2"


def test_round_trip_with_optional_columns_and_gaps(tmp_path):
    t = np.array([0.0, 0.001, 0.0021, 0.003])
    sig = {"acc_b": np.array([0.1, -0.2, np.nan, 0.4]),
           "gyro_b": np.array([1e-3, 2e-3, 3e-3, 4e-3]),
           "acc_bd": np.array([0.01, 0.02, 0.03, 0.04]), "speed": np.full(4, 42.5),
           "acc_w1": np.zeros(4), "acc_w2": np.ones(4)}
    write_csv(tmp_path / "r.csv", t, sig)
    rec = read_csv(tmp_path / "r.csv")
    np.testing.assert_array_equal(rec.t_s, t)
    assert rec.sensors == ("acc_w1", "acc_w2", "acc_b", "gyro_b", "acc_bd")
    for k, v in sig.items():
        np.testing.assert_array_equal(rec.signals[k], v)
    assert rec.matrix(("acc_b", "gyro_b", "acc_bd")).shape == (4, 3)


@pytest.mark.parametrize("text, line, column, words", [
    ("time_s,bogie_lat_acc_mps2,body_lat_acc_mps2\n0,1,2\n", 1, "bogie_yaw_rate_radps", "missing"),
    (HEADER + "\n0,1,2,3\n0.001,1,abc,3\n", 3, "bogie_yaw_rate_radps", "'abc'"),
    (HEADER + "\n0,1,2,3\n0,1,2,3\n", 3, "time_s", "increase"),
    (HEADER + "\n0,1,2\n", 2, None, "expected 4 fields, got 3"),
    (HEADER + "\n,1,2,3\n", 2, "time_s", "empty"),
    (HEADER + "\n0,inf,2,3\n", 2, "bogie_lat_acc_mps2", "finite"),
    ("", 1, None, "header"),
    (HEADER + "\n", 2, None, "at least one data row"),
])
def test_malformed_csv_names_line_and_column(tmp_path, text, line, column, words):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(CsvFormatError) as info:
        read_csv(path)
    err = info.value
    assert err.line == line and err.column == column
    assert words in str(err) and f"bad.csv:{line}" in str(err)


def test_missing_wheelset_columns_for_five_sensors(tmp_path):
    path = tmp_path / "r.csv"
    path.write_text(HEADER + "\n0,1,2,3\n")
    with pytest.raises(CsvFormatError, match="wheelset1_lat_acc_mps2"):
        read_csv(path).matrix(("acc_w1", "acc_w2", "acc_b", "gyro_b", "acc_bd"))
