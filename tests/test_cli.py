import json
import re
import shutil
import subprocess
import sys

import pytest

from deepslam.cli import build_parser, main


def test_every_command_explains_its_options(capsys):
    for argv in (
        ["--help"],
        ["run", "--help"],
        ["replay", "--help"],
        ["drift", "--help"],
        ["eval", "detector", "--help"],
        ["eval", "warp", "--help"],
        ["bench", "detector", "--help"],
        ["bench", "warp", "--help"],
        ["bench", "pipeline", "--help"],
        ["train", "magicpoint", "--help"],
        ["train", "magicwarp", "--help"],
        ["eval", "realimages", "--help"],
        ["eval", "pipeline", "--help"],
        ["train", "magicpoint-ha", "--help"],
        ["train", "export", "--help"],
    ):
        with pytest.raises(SystemExit) as exit_info:
            main(argv)
        assert exit_info.value.code == 0
        out = capsys.readouterr().out
        assert "usage: deepslam" in out
        if argv[0] in ("run", "train") and "export" not in argv:
            assert "(default: " in out  # --help shows every default
        flat = " ".join(out.split())
        assert "(default: None)" not in flat and "(default: False)" not in flat  # no default where there is none
        assert not re.search(r"default[^()]*\) \(default: ", flat)  # each default once
        assert "Config options" not in out and "SourceOptions" not in out  # groups say what they set


def test_help_shows_flags_on_or_off_and_integer_maxima_in_full(capsys):
    with pytest.raises(SystemExit):
        main(["run", "--help"])
    flat = " ".join(capsys.readouterr().out.split())
    assert "MagicWarp matches (default: off)" in flat and "(at most 4294967295) (default: 0)" in flat  # --seed
    assert not re.search(r"\(at most [0-9.]+e\+", flat)  # no 4.29497e+09


def test_contract_flags_of_run():
    args = build_parser().parse_args(
        ["run", "--frontend", "classical", "--frames", "7", "--seed", "3", "--out", "x.mcap"]
    )
    assert (args.frontend, args.frames, args.seed, str(args.out)) == ("classical", 7, 3, "x.mcap")


def test_run_and_drift_end_to_end(tmp_path, capsys):
    log = tmp_path / "run.mcap"
    assert main(["run", "--frontend", "classical", "--frames", "12", "--out", str(log)]) == 0
    out = capsys.readouterr().out
    assert "ate_se3" in out and "scale: map" in out and "scale_drift" in out and log.exists()  # the default scale
    assert main(["drift", str(log), "--out", str(tmp_path / "drift"), "--tum"]) == 0
    assert (tmp_path / "drift" / "drift.png").exists()
    written = (tmp_path / "drift" / "drift.txt").read_bytes()
    with pytest.raises(SystemExit) as exit_info:  # never over earlier results
        main(["drift", str(log), "--out", str(tmp_path / "drift")])
    assert exit_info.value.code == 2 and "holds an earlier drift's results" in capsys.readouterr().err
    assert (tmp_path / "drift" / "drift.txt").read_bytes() == written
    twin = tmp_path / "again" / "run.mcap"  # the same file name in another folder
    twin.parent.mkdir()
    twin.write_bytes(log.read_bytes())
    assert main(["drift", str(log), str(twin), "--out", str(tmp_path / "both"), "--tum"]) == 0
    rows = (tmp_path / "both" / "drift.txt").read_text().splitlines()[1:3]
    assert [row.split()[0] for row in rows] == [f"{tmp_path.name}/run.mcap", "again/run.mcap"]
    tum = sorted(path.name for path in (tmp_path / "both").glob("*.tum"))
    assert tum == [
        f"{name}.{kind}.tum" for name in ("again_run", f"{tmp_path.name}_run") for kind in ("estimate", "groundtruth")
    ]


@pytest.mark.parametrize(
    "scale_drift, warned", [(1.3, False), (0.6, False), (2.5, True), (0.4, True), (float("nan"), False)]
)
def test_a_summary_warns_of_a_scale_that_drifted_beyond_twice(scale_drift, warned, capsys, caplog):
    from deepslam.cli import _print_summary, log

    log.addHandler(caplog.handler)  # the command's logger may not propagate once main() configured it
    try:
        _print_summary({"ate_se3": 0.1, "ate_sim3": 0.05, "scale_drift": scale_drift}, "map")
    finally:
        log.removeHandler(caplog.handler)
    out = capsys.readouterr().out
    assert f"scale_drift          {scale_drift:.4f}" in out and ("needs 8 frames" in out) == (
        scale_drift != scale_drift
    )
    assert ("scale drifted" in caplog.text) == warned and (f"{scale_drift:.2f}x" in caplog.text) == warned


@pytest.mark.parametrize(
    "argv, command",
    [(["run", "--frmes", "3"], "deepslam run"), (["replay", "a.mcap", "--frames", "3"], "deepslam replay"),
     (["train", "export", "a.pt", "b.pt", "--fast"], "deepslam train export"), (["--fast", "run"], "deepslam run")],
)  # fmt: skip
def test_an_unknown_option_is_named_with_the_command_it_was_given_to(argv, command, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    error = capsys.readouterr().err
    assert exit_info.value.code == 2 and error.count("\n") == 1
    assert error.startswith(f"{command}: error: unrecognized arguments: ") and f"see {command} --help" in error


def test_usage_errors_exit_2_and_runtime_errors_exit_1_with_one_line(tmp_path, capsys):
    log, folder = str(tmp_path / "r.mcap"), str(tmp_path / "eval")
    clip = tmp_path / "clip.mp4"
    clip.write_bytes(b"not read: the missing calibration is found first")
    for argv, message in [  # options checked before any work starts, the option named
        (["run", "--frames", "1", "--out", log], "argument --frames: must lie in [2, 100000], got '1'"),
        (["run", "--size", "100", "160", "--out", log], "divisible by 8"),
        (["run", "--fps", "inf", "--out", log], "argument --fps: must be finite, got 'inf'"),
        (["run", "--lighting", "nan", "--out", log], "argument --lighting: must be finite, got 'nan'"),
        (["run", "--oracle-noise", "inf", "--out", log], "argument --oracle-noise: must be finite"),
        (["run", "--keyframe-parallax", "-1", "--out", log], "keyframe parallax must be positive"),
        (["run", "--warp-iterations", "0", "--out", log], "argument --warp-iterations: must lie in [1, 10]"),
        (["run", "--seed", "-1", "--out", log], "argument --seed: must lie in [0, "),
        (["eval", "pipeline", "--seeds", "0", "--out", folder], "argument --seeds: must lie in [1, 1000]"),
        (["bench", "warp", "--repeats", "0"], "argument --repeats: must lie in [1, 100000]"),
        (["bench", "pipeline", "--frames", "1"], "argument --frames: must lie in [2, 100000]"),
        (["bench", "pipeline", "--rounds", "0"], "argument --rounds: must lie in [1, 100]"),
        (["drift", log, "--delta", "-1"], "argument --delta: must lie in [1, 100000]"),
        (["train", "magicwarp", "--batch", "0", "--out", folder], "argument --batch: must lie in [1, 4096]"),
        (["train", "magicwarp", "--lr", "inf", "--out", folder], "argument --lr: must be finite"),
        (["train", "magicpoint", "--ema", "1", "--out", folder], "argument --ema: must lie in [0, 0.999999]"),
        (["train", "magicwarp", "--max-extra", "1.5", "--out", folder], "argument --max-extra: must lie in [0, 1]"),
        (
            ["train", "magicpoint", "--clean-share", "half", "--out", folder],
            "argument --clean-share: expected a number",
        ),
        (["eval", "detector", "--detectors", "Nope", "--out", folder], "unknown or unavailable detectors ['Nope']"),
        (["eval", "warp", "--out", __file__], "is a file, not a folder"),
        (["replay", str(tmp_path / "missing.mcap"), "--out", log], "missing.mcap: no such file or folder"),
        (["replay", str(clip), "--out", log], "clip.mp4: a video carries no calibration; give --calibration FILE"),
        (["drift", str(tmp_path / "missing.mcap")], "missing.mcap: no such file or folder"),
        (["report", str(tmp_path / "missing.mcap")], "missing.mcap: no such file or folder"),
        (["recover", str(tmp_path / "missing.mcap"), "--out", log], "missing.mcap: no such file or folder"),
        (["run", "--out", f"{tmp_path / 'runs'}/"], "runs/ ends in /, as a folder does; give a file name"),
        (["report", log, "--out", f"{tmp_path / 'pages'}/"], "pages/ ends in /, as a folder does"),
    ]:
        with pytest.raises(SystemExit) as exit_info:
            main(argv)
        assert exit_info.value.code == 2, argv
        assert message in capsys.readouterr().err, argv
    garbage = tmp_path / "g.mcap"
    garbage.write_bytes(b"hello")
    for argv, message in [  # runtime errors: one line, exit 1
        (["drift", str(garbage), "--out", folder], "not an MCAP file"),
        (["eval", "pipeline", "--worlds", "plane", "--trajectories", "forward", "--out", folder], "would hit the wall"),
    ]:
        assert main(argv) == 1, argv
        err = capsys.readouterr().err
        assert message in err and err.count("\n") == 1 and "Traceback" not in err, argv
    assert not (tmp_path / "r.mcap").exists() and not (tmp_path / "eval").exists()  # bad input leaves nothing behind


def test_cli_defaults_are_the_config_defaults():
    """Every option that a config dataclass offers has the dataclass's default: one source for each setting."""
    import dataclasses

    from deepslam.backend.config import OdometryConfig
    from deepslam.backend.evaluation.sweep import SweepConfig
    from deepslam.frontend.config import MagicWarpConfig, TrackerConfig
    from deepslam.frontend.training import adaptation, magicpoint, magicwarp
    from deepslam.options import options_of
    from deepslam.sim.scenario import ScenarioConfig

    parser = build_parser()
    for argv, configs in [
        (["run"], (ScenarioConfig, TrackerConfig, OdometryConfig)),
        (["replay", "x.mcap"], (TrackerConfig, OdometryConfig)),
        (["eval", "pipeline"], (SweepConfig,)),
        (["train", "magicpoint"], (magicpoint.TrainConfig,)),
        (["train", "magicwarp"], (magicwarp.TrainConfig, MagicWarpConfig)),
        (["train", "magicpoint-ha"], (adaptation.AdaptConfig,)),
    ]:
        args = parser.parse_args(argv)
        for config in configs:
            defaults = config()
            names = options_of(config)
            assert names, config
            for name in names:
                value = getattr(args, name)
                assert (tuple(value) if isinstance(value, list) else value) == getattr(defaults, name), (argv, name)
            assert {f.name for f in dataclasses.fields(config)} >= set(names)


@pytest.mark.slow
def test_python_m_deepslam_and_version(capsys):
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-m", "deepslam", "--version"], capture_output=True, text=True, check=True)
    assert out.stdout.startswith("deepslam ")
    with pytest.raises(SystemExit) as exit_info:
        main(["--version"])
    assert exit_info.value.code == 0


@pytest.mark.slow
def test_eval_detector_writes_table_json_and_plots(tmp_path, capsys):
    assert main(["eval", "detector", "--per-category", "2", "--sweep-per-category", "1", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "Harris" in out and "MagicPointS" in out
    result = json.loads((tmp_path / "detector.json").read_text())
    assert set(result["detectors"]) >= {"FAST", "Harris", "Shi", "MagicPointS"}
    assert len(list(tmp_path.glob("*.png"))) == 3


@pytest.mark.slow
def test_parallel_evaluations_give_the_serial_bytes(tmp_path, capsys):
    sweep = ["eval", "pipeline", "--worlds", "plane", "--trajectories", "circle", "--noise", "0", "--lighting", "0",
             "--seeds", "3", "--frames", "8", "--frontends", "oracle", "classical", "-q"]  # fmt: skip
    real = ["eval", "realimages", "--frames", "3", "--detectors", "Harris", "MagicPointS", "-q"]
    for argv, name in ((sweep, "pipeline.json"), (real, "realimages.json")):
        assert main([*argv, "--out", str(tmp_path / "serial")]) == 0
        assert main([*argv, "--out", str(tmp_path / "jobs"), "--jobs", "2"]) == 0
        assert (tmp_path / "serial" / name).read_bytes() == (tmp_path / "jobs" / name).read_bytes(), name
    at = sweep.index("--seeds")
    on = [*sweep[:at], "--seeds", "2", "--first-seed", "1", *sweep[at + 2 :], "--out", str(tmp_path / "on")]
    assert main(on) == 0
    serial, later = (json.loads((tmp_path / f / "pipeline.json").read_text())["rows"] for f in ("serial", "on"))
    assert [row["runs"] for row in later] == [row["runs"][1:] for row in serial]  # seeds 1 and 2, as before
    with pytest.raises(SystemExit) as exit_info:
        main([*sweep, "--jobs", "0"])
    assert exit_info.value.code == 2 and "argument --jobs: must lie in [1, 256]" in capsys.readouterr().err


@pytest.mark.slow
def test_realimages_evaluates_a_checkpoint_beside_the_shipped_detectors(tmp_path, capsys):
    from deepslam.frontend.magicpoint import WEIGHTS

    candidate = tmp_path / "candidate.pt"
    shutil.copy(WEIGHTS / "magicpoint_S-HA.pt", candidate)
    argv = ["eval", "realimages", "--frames", "2", "--detectors", "MagicPointS-HA", "-q", "--out", str(tmp_path)]
    assert main([*argv, "--weights", str(candidate)]) == 0
    result = json.loads((tmp_path / "realimages.json").read_text())
    assert set(result) == {"MagicPointS-HA", str(candidate)}
    assert result[str(candidate)] == result["MagicPointS-HA"]  # the same weights, run the same way
    (tmp_path / "broken.pt").write_bytes(b"not weights")
    capsys.readouterr()
    assert main([*argv, "--weights", str(tmp_path / "broken.pt")]) == 1
    error = capsys.readouterr().err
    assert "broken.pt is not a deepslam weights file" in error and len(error.strip().splitlines()) == 1


def test_ray_without_ray_says_how_to_get_it(tmp_path, capsys):
    pytest.importorskip("torch")
    try:
        import ray  # noqa: F401

        pytest.skip("Ray is installed here")
    except ImportError:
        pass
    assert main(["eval", "warp", "--runs", "1", "--ray", "127.0.0.1:6379", "--out", str(tmp_path)]) == 1
    assert 'pip install -e ".[ray]"' in capsys.readouterr().err


def test_ray_needs_the_address_of_a_cluster_started_on_purpose(tmp_path, capsys):
    # Ray listens on every network interface whatever node address it is given: no cluster is started here
    with pytest.raises(SystemExit) as exit_info:
        main(["eval", "warp", "--runs", "1", "--ray", "--out", str(tmp_path)])
    assert exit_info.value.code == 2 and "argument --ray: expected one argument" in capsys.readouterr().err
    pytest.importorskip("ray")
    assert main(["eval", "warp", "--runs", "1", "--ray", "127.0.0.1:1", "--out", str(tmp_path)]) == 1
    assert "cannot reach a Ray cluster at 127.0.0.1:1" in capsys.readouterr().err


def test_help_and_version_start_without_torch():
    import subprocess
    import sys

    for argv in (["--version"], ["--help"], ["run", "--help"], ["eval", "pipeline", "--help"]):
        code = (
            "import sys\nfrom deepslam.cli import main\ntry:\n    main(" + repr(argv) + ")\nexcept SystemExit:\n"
            "    pass\nprint('torch' in sys.modules, 'gtsam' in sys.modules)"
        )
        result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
        assert result.stdout.strip().splitlines()[-1] == "False False", (argv, result.stderr)


@pytest.mark.parametrize(
    "argv, option",
    [
        (["run", "--size", "100000", "100000"], "--size"),
        (["run", "--frames", "99999999999999999999"], "--frames"),
        (["run", "--speed", "1e12"], "--speed"),
        (["run", "--warp-iterations", "100000"], "--warp-iterations"),
        (["drift", "x.mcap", "--delta", "1000000"], "--delta"),
        (["eval", "pipeline", "--seeds", "100000"], "--seeds"),
    ],
)
def test_an_option_past_its_documented_maximum_is_a_usage_error(argv, option, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2 and f"argument {option}: must lie in" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main([*argv[: 2 if argv[0] == "eval" else 1], "--help"])
    assert "(at most " in capsys.readouterr().out  # the maximum is documented


@pytest.mark.slow
def test_sigterm_stops_a_parallel_sweep_and_its_workers_within_seconds(tmp_path):
    import signal
    import subprocess
    import sys
    import time

    marker = tmp_path / "sweep_marker"
    argv = ["eval", "pipeline", "--worlds", "plane", "--trajectories", "circle", "--frontends", "magic",
            "--noise", "0", "--lighting", "0", "--seeds", "4", "--jobs", "2", "-q", "--out", str(marker)]  # fmt: skip
    process = subprocess.Popen([sys.executable, "-m", "deepslam", *argv], stderr=subprocess.PIPE, text=True)

    def running() -> int:  # processes of this sweep: the parent and its workers
        return len(subprocess.run(["pgrep", "-f", str(marker)], capture_output=True).stdout.split())

    deadline = time.time() + 120  # however slow the machine is at the moment
    while time.time() < deadline and running() < 3:
        time.sleep(0.2)
    time.sleep(3)  # the workers are inside their first runs
    process.send_signal(signal.SIGTERM)
    started = time.time()
    assert process.wait(timeout=30) == 143 and time.time() - started < 5
    time.sleep(0.5)
    left = subprocess.run(["pgrep", "-f", str(marker)], capture_output=True, text=True).stdout
    assert not left.strip(), left


_EXIT_IN_A_PROCESS_GROUP = """
import atexit, sys
import torch.distributed as dist
from deepslam.cli import _ended

if sys.argv[2] == "group":
    dist.init_process_group("gloo", init_method=f"file://{sys.argv[1]}", rank=0, world_size=1)
atexit.register(print, " and shut down")
print("trained", end="")  # no newline: still in the buffer of a pipe
sys.exit(_ended(3))
"""


@pytest.mark.parametrize("group", ["group", "alone"])
def test_a_rank_of_a_process_group_exits_with_its_status_and_output_but_no_shutdown(tmp_path, group):
    # a gloo thread may still be letting go of a collective's tensors as Python shuts down, which aborts the process
    command = [sys.executable, "-c", _EXIT_IN_A_PROCESS_GROUP, str(tmp_path / "store"), group]
    ended = subprocess.run(command, capture_output=True, text=True, timeout=120)
    assert ended.returncode == 3, ended.stderr[-2000:]
    assert ended.stdout == ("trained" if group == "group" else "trained and shut down\n")
