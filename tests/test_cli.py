import json

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
    ):
        with pytest.raises(SystemExit) as exit_info:
            main(argv)
        assert exit_info.value.code == 0
        assert "usage: deepslam" in capsys.readouterr().out


def test_contract_flags_of_run():
    args = build_parser().parse_args(
        ["run", "--frontend", "classical", "--frames", "7", "--seed", "3", "--out", "x.mcap"]
    )
    assert (args.frontend, args.frames, args.seed, str(args.out)) == ("classical", 7, 3, "x.mcap")


def test_run_and_drift_end_to_end(tmp_path, capsys):
    log = tmp_path / "run.mcap"
    assert main(["run", "--frontend", "classical", "--frames", "12", "--out", str(log)]) == 0
    out = capsys.readouterr().out
    assert "ate_se3" in out and "scale: gt" in out and log.exists()
    assert main(["drift", str(log), "--out", str(tmp_path / "drift"), "--tum"]) == 0
    assert (tmp_path / "drift" / "drift.png").exists()


def test_bad_input_gets_a_clear_error(tmp_path, capsys):
    garbage = tmp_path / "g.mcap"
    garbage.write_bytes(b"hello")
    assert main(["drift", str(garbage)]) == 2
    assert "not an MCAP file" in capsys.readouterr().err
    assert main(["run", "--frames", "1", "--out", str(tmp_path / "r.mcap")]) == 2
    assert "at least 2 frames" in capsys.readouterr().err
    assert main(["run", "--size", "100", "160", "--out", str(tmp_path / "r.mcap")]) == 2
    assert "divisible by 8" in capsys.readouterr().err
    log, folder = str(tmp_path / "r.mcap"), str(tmp_path / "eval")
    for argv, message in [
        (["run", "--keyframe-parallax", "-1", "--out", log], "keyframe parallax must be positive"),
        (["run", "--warp-iterations", "0", "--out", log], "iterations and the budget must be at least 1"),
        (["eval", "pipeline", "--seeds", "0", "--out", folder], "at least one"),
        (["replay", str(tmp_path / "missing.mcap"), "--out", log], "no such file"),
        (["run", "--seed", "-1", "--out", log], "seed must be non-negative"),
        (["bench", "warp", "--repeats", "0"], "at least 1 repetition"),
        (["bench", "pipeline", "--frames", "1"], "a run needs at least 2 frames, got 1"),
        (["train", "magicwarp", "--batch", "0", "--out", folder], "--batch must be at least 1"),
        (
            ["train", "magicpoint", "--iterations", "0", "--ema", "1", "--out", folder],
            "--iterations must be at least 1, got 0; --ema must lie in [0, 1)",
        ),
    ]:
        assert main(argv) == 2
        assert message in capsys.readouterr().err
    for argv, message in [
        (
            ["train", "magicwarp", "--max-extra", "1.5", "--out", folder],
            "argument --max-extra: must be a number in [0, 1], got '1.5'",
        ),
        (
            ["train", "magicwarp", "--clean-a-share", "2", "--out", folder],
            "argument --clean-a-share: must be a number in [0, 1], got '2'",
        ),
        (
            ["train", "magicpoint", "--clean-share", "half", "--out", folder],
            "argument --clean-share: must be a number in [0, 1], got 'half'",
        ),
    ]:
        with pytest.raises(SystemExit) as exit_info:  # argparse rejects these before any work starts
            main(argv)
        assert exit_info.value.code == 2
        assert message in capsys.readouterr().err
    assert not (tmp_path / "r.mcap").exists() and not (tmp_path / "eval").exists()  # bad input leaves nothing behind


def test_eval_detector_writes_table_json_and_plots(tmp_path, capsys):
    assert main(["eval", "detector", "--per-category", "2", "--sweep-per-category", "1", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "Harris" in out and "MagicPointS" in out
    result = json.loads((tmp_path / "detector.json").read_text())
    assert set(result["detectors"]) >= {"FAST", "Harris", "Shi", "MagicPointS"}
    assert len(list(tmp_path.glob("*.png"))) == 3
