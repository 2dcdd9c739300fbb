"""The examples the README points to run as they are."""

import runpy
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).parent.parent / "examples"


@pytest.mark.parametrize("name", ["quickstart.py", "pose_graph.py"])
def test_example_runs(name, capsys):
    runpy.run_path(str(EXAMPLES / name), run_name="__main__")
    assert capsys.readouterr().out.strip()


def test_shift_repeatability_example_scores_a_whole_cell_shift_as_no_shift(capsys, monkeypatch):
    argv = ["shift_repeatability.py", "--detectors", "MagicPointS-HA", "Harris", "--shifts", "0", "8"]
    monkeypatch.setattr("sys.argv", argv)
    runpy.run_path(str(EXAMPLES / "shift_repeatability.py"), run_name="__main__")
    rows = [line.split() for line in capsys.readouterr().out.splitlines()[1:]]
    assert [row[0] for row in rows] == ["MagicPointS-HA", "Harris"]
    for row in rows:  # no shift repeats every point in place; a whole cell moves the grid with the image
        assert float(row[1]) == 1.0 and float(row[3]) > 0.85, row
