"""The examples the README points to run as they are."""

import runpy
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

EXAMPLES = Path(__file__).parent.parent / "examples"


@pytest.mark.parametrize("name", ["quickstart.py", "pose_graph.py"])
def test_example_runs(name, capsys):
    runpy.run_path(str(EXAMPLES / name), run_name="__main__")
    assert capsys.readouterr().out.strip()


@pytest.mark.parametrize(
    "name",
    ["bundle_adjusters.py", "first_frames.py", "limit_split.py", "located_precision.py", "own_frames.py",
     "shift_repeatability.py", "subpixel_precision.py", "track_consistency.py", "track_survival.py"],
)  # fmt: skip
def test_example_help_says_its_whole_first_paragraph(name, capsys, monkeypatch):
    monkeypatch.setattr("sys.argv", [name, "--help"])
    with pytest.raises(SystemExit) as exit_info:
        runpy.run_path(str(EXAMPLES / name), run_name="__main__")
    paragraph = (EXAMPLES / name).read_text().split('"""')[1].split("\n\n")[0].split()
    shown = capsys.readouterr().out.split()
    assert exit_info.value.code == 0 and " ".join(paragraph[-4:]) in " ".join(shown)


def test_shift_repeatability_example_scores_a_whole_cell_shift_as_no_shift(capsys, monkeypatch):
    argv = ["shift_repeatability.py", "--detectors", "MagicPointS-HA", "Harris", "--shifts", "0", "8"]
    monkeypatch.setattr("sys.argv", argv)
    runpy.run_path(str(EXAMPLES / "shift_repeatability.py"), run_name="__main__")
    rows = [line.split() for line in capsys.readouterr().out.splitlines()[1:]]
    assert [row[0] for row in rows] == ["MagicPointS-HA", "Harris"]
    for row in rows:  # no shift repeats every point in place; a whole cell moves the grid with the image
        assert float(row[1]) == 1.0 and float(row[3]) > 0.85, row


@pytest.mark.slow
def test_subpixel_precision_example_finds_parabola_labels_follow_a_sub_pixel_shift_closer(capsys, monkeypatch):
    monkeypatch.setattr("sys.argv", ["subpixel_precision.py", "--views", "3"])  # the built-in validation photographs
    runpy.run_path(str(EXAMPLES / "subpixel_precision.py"), run_name="__main__")
    rows = {line.split()[0]: line.split() for line in capsys.readouterr().out.splitlines()[2:]}
    assert sorted(rows) == ["centroid", "none", "parabola", "smoothed"]
    label_mean = {refine: float(row[1]) for refine, row in rows.items()}
    assert label_mean["parabola"] < label_mean["none"], label_mean
    assert all(int(row[4].strip("()")) > 0 and int(row[8].strip("()")) > 0 for row in rows.values()), rows


def test_own_frames_example_runs_the_pipeline_on_a_folder_of_images(tmp_path, capsys, monkeypatch):
    import cv2

    from deepslam.sim.scenario import Scenario, ScenarioConfig

    scenario = Scenario(ScenarioConfig(world="plane", trajectory="line", frames=12))
    for index, frame in enumerate(scenario):
        cv2.imwrite(str(tmp_path / f"{index:03d}.png"), frame.image)
    fx, fy, cx, cy = scenario.K[0, 0], scenario.K[1, 1], scenario.K[0, 2], scenario.K[1, 2]
    argv = ["own_frames.py", str(tmp_path), "--frontend", "classical", "--K", *map(str, (fx, fy, cx, cy))]
    monkeypatch.setattr("sys.argv", argv)
    runpy.run_path(str(EXAMPLES / "own_frames.py"), run_name="__main__")
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 13 and lines[-1].startswith("12 frames")
    assert not any(line.endswith("lost True") for line in lines[:-1])
    assert float(lines[-1].split("path length ")[1].split()[0]) > 0  # it moved
    (tmp_path / "012.png").write_bytes(b"not an image")  # sorted after the frames: they run first
    for extra, message in [([], "012.png: not a readable image"), (["--fps", "0"], "--fps must be positive")]:
        monkeypatch.setattr("sys.argv", [*argv, *extra])
        with pytest.raises(SystemExit) as exit_info:  # one line, no traceback
            runpy.run_path(str(EXAMPLES / "own_frames.py"), run_name="__main__")
        assert exit_info.value.code in (1, 2) and message in capsys.readouterr().err


def test_the_sample_calibration_file_reads_as_a_camera():
    from deepslam.inputs import Calibration

    camera = Calibration.from_yaml(EXAMPLES / "calibration.yaml", (480, 640))
    assert camera.model == "plumb_bob" and camera.size == (480, 640) and camera.K[0, 0] == 517.3


def test_track_consistency_example_finds_followed_tracks_on_their_points_more_often(capsys, monkeypatch):
    argv = ["track_consistency.py", "--worlds", "clutter", "--seeds", "0", "--frames", "12"]
    monkeypatch.setattr("sys.argv", argv)
    runpy.run_path(str(EXAMPLES / "track_consistency.py"), run_name="__main__")
    row = capsys.readouterr().out.splitlines()[2].split()
    assert row[:2] == ["clutter", "0"]
    snapped, followed = float(row[2]), float(row[3])
    assert 0 < snapped < followed <= 1, row


def test_limit_split_example_measures_each_run_over_its_limit_from_the_map_on(capsys, monkeypatch):
    argv = ["limit_split.py", "--frontend", "oracle", "--worlds", "plane", "clutter", "--trajectories", "circle"]
    monkeypatch.setattr("sys.argv", [*argv, "forward", "--seeds", "1", "--frames", "20"])
    runpy.run_path(str(EXAMPLES / "limit_split.py"), run_name="__main__")
    lines = capsys.readouterr().out.splitlines()
    rows = [line.split() for line in lines[1:-1]]
    assert [row[:2] for row in rows] == [["plane", "circle"], ["clutter", "circle"], ["clutter", "forward"]]
    starts, whole, after, own = (np.array([float(row[i]) for row in rows]) for i in (3, 4, 5, 7))
    assert starts[0] < 10 and np.all(whole > 0) and np.all(after[np.isfinite(after)] > 0)
    assert np.isnan(after[starts > 17]).all()  # no three frames in a map to measure
    assert own[0] > 0 and np.isnan(own[starts == 20]).all()  # the plane's map starts from frame 0; none: no baseline
    assert lines[-1].startswith(f"median {np.median(whole):.2f} (3 runs)")
    monkeypatch.setattr("sys.argv", ["limit_split.py", "--seeds", "0"])
    with pytest.raises(SystemExit) as exit_info:  # a usage error, not a traceback
        runpy.run_path(str(EXAMPLES / "limit_split.py"), run_name="__main__")
    assert exit_info.value.code == 2 and "--seeds must be at least 1" in capsys.readouterr().err


def test_located_precision_example_puts_pnp_on_true_points_under_the_located_frames(capsys, monkeypatch):
    argv = ["located_precision.py", "--worlds", "room", "--trajectories", "forward", "--seeds", "1", "--frames", "30"]
    monkeypatch.setattr("sys.argv", argv)
    runpy.run_path(str(EXAMPLES / "located_precision.py"), run_name="__main__")
    (row,) = [line.replace("/", " ").split() for line in capsys.readouterr().out.splitlines()[1:]]
    located, measured, unscaled, own, every, inliers, tracks = (float(value) for value in row[3:])
    assert row[:3] == ["room", "forward", "0"] and 10 <= located < 30
    assert 0 < every <= own < measured < 50  # true points locate better than the map; all tracks better than some
    assert 0 < unscaled < measured  # the map's scale is part of its error
    assert 12 <= inliers < tracks <= 150
    monkeypatch.setattr("sys.argv", ["located_precision.py", "--frontend", "magic"])
    with pytest.raises(SystemExit, match="only the oracle's tracks have true 3-D points"):
        runpy.run_path(str(EXAMPLES / "located_precision.py"), run_name="__main__")


def test_first_frames_example_recovers_a_direction_given_the_rotation_and_bins_frames_by_flow(capsys, monkeypatch):
    example = runpy.run_path(str(EXAMPLES / "first_frames.py"))
    rng = np.random.default_rng(0)
    points_1 = np.c_[rng.uniform(-1, 1, (40, 2)), rng.uniform(2, 6, 40)]
    R_2_1 = Rotation.from_euler("xyz", [2.0, -5.0, 1.0], degrees=True).as_matrix()
    t = np.array([0.3, -0.1, 0.5])
    points_2 = points_1 @ R_2_1.T + t
    direction = example["direction_given_rotation"](R_2_1, points_1 / points_1[:, 2:], points_2 / points_2[:, 2:])
    np.testing.assert_allclose(direction, t / np.linalg.norm(t), atol=1e-9)  # the sign too: points in front
    argv = ["first_frames.py", "--worlds", "clutter", "--trajectories", "forward", "--seeds", "1", "--frames", "30"]
    monkeypatch.setattr("sys.argv", argv)
    runpy.run_path(str(EXAMPLES / "first_frames.py"), run_name="__main__")
    _, header, *rows = capsys.readouterr().out.splitlines()
    assert header.split()[:2] == ["flow", "px"] and rows
    values = np.array([row.replace("/", " ").split()[1:] for row in rows], float)  # frames, then median / 90th
    assert values[:, 0].sum() >= 10  # the map starts after frame 10 on this path
    medians, top = values[:, 1::2], values[:, 2::2]
    assert np.all(medians <= top) and np.all(medians[:, :3] <= 180) and np.all(medians[:, 3] > 0)


def test_bundle_adjusters_example_solves_the_maps_windows_with_gtsam_and_pycolmap(capsys, monkeypatch):
    monkeypatch.setattr("sys.argv", ["bundle_adjusters.py", "--seeds", "0", "--frames", "40"])
    runpy.run_path(str(EXAMPLES / "bundle_adjusters.py"), run_name="__main__")
    windows, times, depths = capsys.readouterr().out.splitlines()
    assert int(windows.split()[0]) > 0 and "room circle, clutter circle, clutter forward" in windows
    gtsam_ms, pycolmap_ms = (float(word.strip(",")) for word in times.split()[-3::2])
    before, gtsam_error, pycolmap_error = (float(word.strip(",")) for word in depths.split()[-5::2])
    assert gtsam_ms > 0 and pycolmap_ms > 0
    assert 0 < gtsam_error < 0.1 and 0 < pycolmap_error < 0.1 and gtsam_error <= 1.5 * before
    monkeypatch.setattr("sys.argv", ["bundle_adjusters.py", "--seeds", "0", "--frames", "4"])
    with pytest.raises(SystemExit) as exit_info:  # no window to adjust: a usage error, not a traceback
        runpy.run_path(str(EXAMPLES / "bundle_adjusters.py"), run_name="__main__")
    assert exit_info.value.code == 2 and "more --frames" in capsys.readouterr().err
