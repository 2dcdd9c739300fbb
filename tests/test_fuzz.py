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
