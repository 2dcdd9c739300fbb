"""Seeded, bounded fuzzing: random option values on the command line and random damage to logs. Every
case must end in a result or a clean error (exit 1 or 2, or ``LogError``), never a traceback."""

import warnings

import numpy as np
import pytest

from deepslam.backend.config import OdometryConfig
from deepslam.backend.evaluation.runs import simulate
from deepslam.cli import main
from deepslam.frontend.config import TrackerConfig
from deepslam.logs.reader import LogError, read_frames
from deepslam.sim.scenario import ScenarioConfig

VALUES = ["nan", "inf", "-inf", "-1", "0", "1", "0.5", "2", "7", "1e308", "-1e-9", "abc", "", "3.5e-2", "99999999999"]
RUN_OPTIONS = [
    "--speed", "--fps", "--noise", "--lighting", "--seed", "--oracle-noise", "--keyframe-parallax",
    "--plane-distance", "--warp-iterations", "--size", "--world", "--trajectory", "--method", "--scale",
]  # fmt: skip


@pytest.mark.slow
def test_random_run_options_end_in_a_result_or_a_clean_error(tmp_path, capsys):
    rng = np.random.default_rng(2026)
    for case in range(30):
        argv = ["run", "-q", "--frontend", "oracle", "--frames", "4", "--out", str(tmp_path / f"fuzz{case}.mcap")]
        for option in rng.choice(RUN_OPTIONS, size=int(rng.integers(1, 4)), replace=False):
            values = rng.choice(VALUES, size=2 if option == "--size" else 1)
            argv += [str(option), *map(str, values)]
        try:
            code = main(argv)
        except SystemExit as exit_info:  # argparse's usage errors
            code = exit_info.code
        err = capsys.readouterr().err
        assert code in (0, 1, 2), (argv, code, err)
        assert "Traceback" not in err, argv
        if code:
            assert err.strip().splitlines()[-1].startswith(("deepslam: error:", "deepslam run: error:")), (argv, err)
            assert not (tmp_path / f"fuzz{case}.mcap").exists(), argv  # a failed run writes no log


def test_random_damage_to_a_log_never_returns_a_broken_frame(tmp_path):
    log = tmp_path / "log.mcap"
    simulate(ScenarioConfig(frames=30, seed=1), TrackerConfig("oracle"), OdometryConfig(), log, {}, progress=False)
    data = log.read_bytes()
    complete = {f.stamp_ns: f for f in read_frames(log)}
    rng = np.random.default_rng(7)
    for case in range(40):
        damaged = bytearray(data)
        kind = case % 4
        if kind == 0:  # flip a few bytes
            for position in rng.integers(8, len(data), 3):
                damaged[position] ^= int(rng.integers(1, 256))
        elif kind == 1:  # cut the file short
            damaged = damaged[: int(rng.integers(8, len(data)))]
        elif kind == 2:  # overwrite a run of bytes with garbage
            start = int(rng.integers(8, len(data) - 64))
            damaged[start : start + 64] = rng.integers(0, 256, 64, dtype=np.uint8).tobytes()
        else:  # drop a run of bytes from the middle
            start = int(rng.integers(8, len(data) - 512))
            del damaged[start : start + 512]
        path = tmp_path / f"damaged{case}.mcap"
        path.write_bytes(bytes(damaged))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                frames = list(read_frames(path))
            except LogError:
                continue
        for frame in frames:
            want = complete[frame.stamp_ns]
            assert np.array_equal(frame.image, want.image), case
            assert np.array_equal(frame.T_estimate, want.T_estimate) and np.array_equal(frame.tracks, want.tracks)


FIELD_VALUES = ["nan", "inf", "-1", "0", "", "abc", "1e300", "1e-300", "true", "[1, 2]", "5", "-1.5", "../x.png",
                "/etc/passwd", "0.0.0", "99999999999999999999999"]  # fmt: skip
DATASET_FILES = ["rgb.txt", "groundtruth.txt", "calibration.yaml", "mav0/cam0/data.csv", "mav0/cam0/sensor.yaml",
                 "mav0/state_groundtruth_estimate0/data.csv"]  # fmt: skip


def _damage_text(text: str, rng: np.random.Generator) -> str:
    """One random edit of a dataset file: a field replaced by junk, a field or a line dropped, or a line
    duplicated."""
    lines = text.splitlines() or [""]
    index = int(rng.integers(len(lines)))
    fields = lines[index].replace(",", " , ").split()
    kind = int(rng.integers(4))
    if kind == 0 and fields:
        fields[int(rng.integers(len(fields)))] = str(rng.choice(FIELD_VALUES))
        lines[index] = " ".join(fields).replace(" , ", ",")
    elif kind == 1 and fields:
        del fields[int(rng.integers(len(fields)))]
        lines[index] = " ".join(fields).replace(" , ", ",")
    elif kind == 2:
        del lines[index]
    else:
        lines.insert(index, lines[index])
    return "\n".join(lines) + "\n"


@pytest.mark.slow
def test_random_damage_to_dataset_folders_and_calibrations_ends_in_a_source_or_a_one_line_error(tmp_path):
    import shutil

    from test_sources import _write_calibration, _write_euroc, _write_tum

    from deepslam.inputs import SourceError, SourceOptions, open_source

    log = tmp_path / "log.mcap"
    simulate(ScenarioConfig(frames=4, seed=1), TrackerConfig("classical"), OdometryConfig(), log, {}, progress=False)
    frames = list(read_frames(log))
    pristine = tmp_path / "pristine"
    _write_tum(pristine / "tum", frames)
    _write_euroc(pristine / "euroc", frames)
    _write_calibration(pristine / "tum" / "calibration.yaml", frames[0].K, frames[0].image.shape)
    rng = np.random.default_rng(11)
    for case in range(60):
        work = tmp_path / f"case{case}"
        shutil.copytree(pristine, work)
        name = str(rng.choice(DATASET_FILES))
        folder = work / ("euroc" if name.startswith("mav0") else "tum")
        target = folder / name
        for _ in range(int(rng.integers(1, 3))):
            target.write_text(_damage_text(target.read_text(), rng))
        options = SourceOptions(calibration=str(work / "tum" / "calibration.yaml") if folder.name == "tum" else None)
        try:
            source = open_source(folder, options)
            loaded = list(source.frames())
        except SourceError as error:
            assert "\n" not in str(error) and str(work) in str(error), (case, name, error)
            continue
        assert all(f.image.dtype == np.uint8 and np.isfinite(f.K).all() for f in loaded), (case, name)
        assert all(f.T_world_cam is None or np.isfinite(f.T_world_cam).all() for f in loaded), (case, name)


def _tampered(rng: np.random.Generator):
    """A random change to one kind of bag message (image, camera info or ground truth), as ``_write_bag``
    takes it."""
    import dataclasses

    kind = str(rng.choice(["image", "info", "truth"]))
    weird = [0.0, -1.0, float("nan"), float("inf"), 1e300, 1e6]

    def tamper(what, message, types):
        if what != kind or rng.random() < 0.5:  # some messages of that kind only
            return message
        if what == "image":
            field = str(rng.choice(["encoding", "height", "width", "step", "data"]))
            cut = message.data[: int(rng.integers(len(message.data)))]
            values = {"encoding": str(rng.choice(["16UC1", "bayer_rggb8", "", "rgb8"])),
                      "height": int(rng.choice([0, 1, 100000])), "width": int(rng.choice([0, 3, 100000])),
                      "step": int(rng.choice([0, 1, 7])), "data": cut}  # fmt: skip
            return dataclasses.replace(message, **{field: values[field]})
        if what == "info":
            k = message.k.copy()
            k[int(rng.choice([0, 2, 4, 5]))] = float(rng.choice(weird))
            d = np.array([float(rng.choice(weird))] * 5) if rng.random() < 0.5 else message.d
            return dataclasses.replace(message, k=k, d=d, distortion_model=str(rng.choice(["plumb_bob", "x"])))
        pose = message.pose.pose
        value = float(rng.choice(weird))
        orientation = dataclasses.replace(pose.orientation, x=value, y=value, z=value, w=value)
        return dataclasses.replace(
            message, pose=dataclasses.replace(message.pose, pose=dataclasses.replace(pose, orientation=orientation))
        )

    return tamper


@pytest.mark.slow
def test_random_bag_messages_end_in_a_source_or_a_one_line_error(tmp_path):
    from test_sources import _write_bag

    from deepslam.inputs import SourceError, SourceOptions, open_source

    log = tmp_path / "log.mcap"
    simulate(ScenarioConfig(frames=4, seed=1), TrackerConfig("classical"), OdometryConfig(), log, {}, progress=False)
    frames = list(read_frames(log))
    rng = np.random.default_rng(13)
    for case in range(30):
        bag = tmp_path / f"bag{case}"
        _write_bag(bag, frames, "mono8", tamper=_tampered(rng))
        try:
            source = open_source(bag, SourceOptions(groundtruth_topic="/mocap/odom"))
            loaded = list(source.frames())
        except SourceError as error:
            assert "\n" not in str(error) and str(bag) in str(error), (case, error)
            continue
        assert all(
            np.isfinite(f.K).all() and (f.T_world_cam is None or np.isfinite(f.T_world_cam).all()) for f in loaded
        )
