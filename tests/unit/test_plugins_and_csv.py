import json

import pytest

from hera.csvlog import CsvLog
from hera.measures.counter import Counter
from hera.plugins import UnknownMeasure, find_measure, known_measures
from hera.store import Sample


def test_entry_point_and_module_class_lookups():
    assert "counter" in known_measures()
    assert find_measure("counter") is Counter
    assert find_measure("hera.measures.counter:Counter") is Counter


def test_unknown_measure_lists_the_known_ones():
    with pytest.raises(UnknownMeasure) as e:
        find_measure("nope")
    assert "unknown measure 'nope'" in str(e.value) and "counter" in str(e.value)
    with pytest.raises(UnknownMeasure, match="cannot load measure 'no.such:Thing'"):
        find_measure("no.such:Thing")
    with pytest.raises(TypeError, match="not a subclass of hera.measure.Measure"):
        find_measure("json:dumps")


def test_csv_rows_are_in_the_original_format_with_a_sidecar(tmp_path):
    log = CsvLog(tmp_path, {"sonar": ("range [m]", "x [m]", "y [m]")})
    log.write(Sample("sonar", "s1", 1, 1763780000.123, 0.0, 0.0, (1.5, 0.0, 2.0)))
    log.write(Sample("sonar", "s1", 2, 1763780000.223, 0.0, 0.0, (1.25, 0.0, 2.0)))
    # rows are on disk before close: a killed process loses at most the row in progress
    rows = (tmp_path / "measures" / "sonar_s1.csv").read_text().splitlines()
    assert rows == ["1,1763780000123.0,1.5,0.0,2.0", "2,1763780000223.0,1.25,0.0,2.0"]
    side = json.loads((tmp_path / "measures" / "sonar_s1.columns.json").read_text())
    assert side["columns"][2:] == ["range [m]", "x [m]", "y [m]"]
    log.close()


def test_a_row_cut_short_by_a_killed_logger_is_dropped_before_the_next_one_appends(tmp_path):
    """The logging node killed mid-row and restarted: the new rows started on the partial
    line, which left a malformed row in the middle of the file (eval and replay refuse it)."""
    from hera.recordings import read_csv

    measures = tmp_path / "measures"
    measures.mkdir()
    path = measures / "sonar_s1.csv"
    path.write_text("1,1763780000123.0,1.5\n2,1763780000223.0,1.2")  # killed while writing 2
    log = CsvLog(tmp_path, {"sonar": ("range [m]",)})
    log.write(Sample("sonar", "s1", 3, 1763780000.323, 0.0, 0.0, (1.75,)))
    log.close()
    assert path.read_text() == "1,1763780000123.0,1.5\n3,1763780000323.0,1.75\n"
    assert [s.seq for s in read_csv(path, "sonar", "s1")] == [1, 3]
    whole = measures / "mag_s1.csv"  # a file whose rows are whole is appended to as it is
    whole.write_text("1,1763780000123.0,0.5\n")
    log = CsvLog(tmp_path)
    log.write(Sample("mag", "s1", 2, 1763780000.223, 0.0, 0.0, (0.25,)))
    log.close()
    assert whole.read_text().splitlines() == ["1,1763780000123.0,0.5", "2,1763780000223.0,0.25"]
