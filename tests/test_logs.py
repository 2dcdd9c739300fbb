import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from deepslam.backend import drift
from deepslam.backend.config import OdometryConfig
from deepslam.backend.evaluation import analysis
from deepslam.backend.evaluation.runs import replay, simulate
from deepslam.cli import main
from deepslam.frontend.config import TrackerConfig
from deepslam.geometry import pose_matrix, quaternion_from_matrix
from deepslam.interrupts import held_signals
from deepslam.logs.reader import LogError, read_frames, read_metadata
from deepslam.logs.schemas import TOPICS, ros2_name
from deepslam.logs.writer import LogWriteError, LogWriter, partial_path
from deepslam.sim.scenario import START_TIME_S, ScenarioConfig

START_NS = round(START_TIME_S * 1e9)  # simulated runs start at 2024-01-01 00:00 UTC, not 1970


def _as_logged(T):
    return pose_matrix(T[:3, 3], quaternion_from_matrix(T[:3, :3]))


@pytest.fixture(scope="module")
def oracle_log(tmp_path_factory):
    path = tmp_path_factory.mktemp("logs") / "oracle.mcap"
    result = simulate(
        ScenarioConfig(frames=25, seed=3),
        TrackerConfig("oracle"),
        OdometryConfig(),
        path,
        {"version": "test"},
        progress=False,
    )
    return path, result


def test_run_reads_back_bit_for_bit(oracle_log):
    path, result = oracle_log
    frames = list(read_frames(path))
    assert len(frames) == 25
    for frame, estimate, truth in zip(frames, result["estimate"], result["truth"], strict=False):
        assert np.array_equal(frame.T_estimate, _as_logged(estimate))
        assert np.array_equal(frame.T_groundtruth, _as_logged(truth))
        assert frame.image.dtype == np.uint8 and frame.image.shape == (120, 160)
        assert frame.tracks.shape[1] == 4
    assert frames[0].correspondences is None and frames[1].correspondences.model in ("homography", "essential")
    for frame, diagnostics in zip(frames, result["diagnostics"], strict=True):  # per-frame figures, as computed
        assert frame.diagnostics.tracks == diagnostics.tracks == len(frame.tracks) and not frame.diagnostics.lost
        assert frame.diagnostics.position_error_m == pytest.approx(diagnostics.position_error_m)
        assert (frame.diagnostics.phase, frame.diagnostics.keyframe_reason) == (
            diagnostics.phase, diagnostics.keyframe_reason
        )  # fmt: skip
        assert frame.diagnostics.phase in ("initialising", "tracking")
    assert frames[0].diagnostics.keyframe_reason == "the first frame"
    assert np.isnan(frames[0].diagnostics.correspondence_error_px)  # nothing tracked into the first frame
    assert 0.3 < np.nanmedian([f.diagnostics.correspondence_error_px for f in frames]) < 1.2  # 0.5 px noise
    pair_errors = [f.diagnostics.pair_error_px for f in frames]
    assert np.isnan(pair_errors[0]) and 0.3 < np.nanmedian(pair_errors) < 1.2  # keyframe to frame, the same noise
    meta = read_metadata(path)
    assert meta["frontend"] == "oracle" and meta["scenario"]["seed"] == 3 and meta["version"] == "test"


def test_mcap_library_lists_every_channel_with_its_schema(oracle_log):
    path, _ = oracle_log
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    schemas = {s.id: s for s in summary.schemas.values()}
    channels = {c.topic: schemas[c.schema_id] for c in summary.channels.values()}
    assert set(channels) == set(TOPICS)
    for topic, schema in channels.items():
        assert schema.name == ros2_name(TOPICS[topic]) and schema.encoding == "ros2msg"
        assert summary.channels and all(c.message_encoding == "cdr" for c in summary.channels.values())


@pytest.mark.external
def test_evo_agrees_with_deepslam_drift(oracle_log, tmp_path):
    path, _ = oracle_log
    _, truth, estimate = analysis.load_trajectories(path)
    ours = drift.ate_rmse(estimate, truth)
    zip_path = tmp_path / "ape.zip"
    # evo's tools sit beside the interpreter that runs the tests, on PATH or not (a venv used without activating)
    evo_ape = shutil.which("evo_ape") or str(Path(sys.executable).parent / "evo_ape")
    subprocess.run(
        [
            evo_ape,
            "mcap",
            str(path),
            "/groundtruth/pose",
            "/estimate/pose",
            "-a",
            "--save_results",
            str(zip_path),
            "--no_warnings",
        ],
        check=True,
        capture_output=True,
        timeout=300,
    )
    import zipfile

    stats = json.loads(zipfile.ZipFile(zip_path).read("stats.json"))
    assert stats["rmse"] == pytest.approx(ours, rel=1e-6)


def test_drift_plots_and_tum(oracle_log, tmp_path):
    path, _ = oracle_log
    comparison = analysis.analyse([path, path])
    table = comparison.table().splitlines()
    assert len(table) == 3 and "RMSE" in table[-1] and "mean" in table[-1]  # the header, the one log, the meanings
    plots = comparison.save(tmp_path)
    assert plots[0].stat().st_size > 10_000 and [p.name for p in plots[-2:]] == ["drift.txt", "drift.json"]
    assert (
        json.loads((tmp_path / "drift.json").read_text())[str(path)]["ate_se3"] == comparison.logs[str(path)]["ate_se3"]
    )
    gt, est = analysis.export_tum(path, tmp_path)
    assert len(gt.read_text().splitlines()) == 25 and len(est.read_text().split("\n")[0].split()) == 8


def test_drift_names_logs_whole_and_measures_them_against_the_limit_of_their_tracks(oracle_log, tmp_path):
    path, result = oracle_log
    named = tmp_path / "a_long_name_of_a_clutter_circle_classical_run.mcap"
    named.write_bytes(path.read_bytes())
    comparison = analysis.analyse([named], limit=True)
    figures = comparison.logs[str(named)]
    table = comparison.table().splitlines()
    assert table[1].startswith(named.name + " ") and table[0].split()[-2:] == ["limit", "/limit"]
    assert 0 < figures["limit_ate_se3"] < figures["ate_se3"]  # the oracle's tracks allow less drift than it has
    assert figures["ate_over_limit"] == pytest.approx(figures["ate_se3"] / figures["limit_ate_se3"])
    assert "limit" not in analysis.analyse([named]).table()


def test_drift_says_a_log_without_truth_has_no_drift_to_measure(oracle_log, tmp_path):
    from dataclasses import replace as replaced

    path, _ = oracle_log
    frames = list(read_frames(path))
    for with_truth, message in [
        (0, "no frame has ground truth (/groundtruth/pose), so there is no drift to measure"),
        (1, "fewer than 2 frames with both /groundtruth/pose and /estimate/pose"),
    ]:
        log = tmp_path / f"truth_{with_truth}.mcap"
        with LogWriter(log, read_metadata(path)) as writer:
            for index, frame in enumerate(frames):
                writer.write(frame if index < with_truth else replaced(frame, T_groundtruth=None))
        assert len(list(read_frames(log))) == len(frames)
        with pytest.raises(LogError, match=re.escape(f"{log}: {message}")):
            analysis.load_trajectories(log)


def test_garbage_and_foreign_files_get_clear_errors(tmp_path):
    garbage = tmp_path / "garbage.mcap"
    garbage.write_bytes(os.urandom(5000))
    with pytest.raises(LogError, match="not an MCAP file"):
        list(read_frames(garbage))
    with pytest.raises(LogError, match="no such file"):
        list(read_frames(tmp_path / "missing.mcap"))
    from mcap.writer import Writer

    foreign = tmp_path / "foreign.mcap"
    with open(foreign, "wb") as f:
        writer = Writer(f)
        writer.start()
        schema = writer.register_schema("x", "jsonschema", b"{}")
        channel = writer.register_channel("/other", "json", schema)
        writer.add_message(channel, 1, b"{}", 1)
        writer.finish()
    with pytest.raises(LogError, match="lacks the topics /camera/image, /camera/camera_info"):
        list(read_frames(foreign))


def test_truncated_file_reads_up_to_its_last_whole_chunk(oracle_log, tmp_path):
    path, _ = oracle_log
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * 0.85)])  # past the first 256 KiB chunk
    with pytest.warns(UserWarning, match="truncated"):
        frames = list(read_frames(cut))
    complete = list(read_frames(path))
    assert 0 < len(frames) < len(complete)
    for got, want in zip(frames, complete, strict=False):
        assert got.stamp_ns == want.stamp_ns and np.array_equal(got.T_estimate, want.T_estimate)


def _default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _run_until(out: Path, size: int, options: tuple[str, ...] = ("--frontend", "oracle")) -> subprocess.Popen:
    """A real `deepslam run` subprocess (with ``options``), returned once its log in progress
    (``OUT.partial``) has grown past ``size`` bytes."""
    process = subprocess.Popen(
        [sys.executable, "-m", "deepslam", "run", *options, "--frames", "400", "--out", str(out)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        preexec_fn=_default_sigint,  # as from a terminal, even where the test runner was started with Ctrl-C ignored
    )
    partial = partial_path(out)
    deadline = time.time() + 240
    while time.time() < deadline and (not partial.exists() or partial.stat().st_size < size):
        assert process.poll() is None, f"the run ended early: {process.communicate()[1].decode()[-2000:]}"
        time.sleep(0.2)
    assert partial.exists() and partial.stat().st_size >= size, f"the log did not reach {size} bytes in 240 s"
    return process


@pytest.mark.slow
def test_killed_run_keeps_its_frames_in_partial_and_recover_finishes_them(tmp_path):
    out = tmp_path / "killed.mcap"
    out.write_bytes(b"the previous log")
    process = _run_until(out, 700_000)
    process.send_signal(signal.SIGKILL)
    process.wait()
    assert out.read_bytes() == b"the previous log"  # an unfinished run leaves the existing output alone
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        frames = list(read_frames(partial_path(out)))
    assert any("truncated" in str(w.message) for w in caught)
    assert len(frames) >= 20  # at least two 256 KiB chunks of ~16 KiB frames were complete
    stamps = [f.stamp_ns for f in frames]
    assert stamps == [START_NS + round(i * 1e8) for i in range(len(frames))]  # 10 fps from the epoch, no gap
    assert all(f.T_estimate is not None and f.T_groundtruth is not None for f in frames)
    fixed = tmp_path / "fixed.mcap"
    assert main(["recover", str(partial_path(out)), "--out", str(fixed)]) == 0
    with open(fixed, "rb") as f:
        assert make_reader(f).get_summary().statistics.message_count > 0  # a seeking reader opens it
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # nothing is missing any more
        recovered = list(read_frames(fixed))
    assert [f.stamp_ns for f in recovered] == stamps
    assert read_metadata(fixed)["scenario"]["frames"] == 400
    assert main(["recover", str(fixed), "--out", str(fixed)]) == 1  # never over its input


def test_corrupt_chunks_are_named_skipped_and_never_leave_a_frame_half_read(oracle_log, tmp_path):
    path, _ = oracle_log
    data = bytearray(path.read_bytes())
    complete = list(read_frames(path))
    rng = np.random.default_rng(0)
    for trial in range(12):
        damaged = data.copy()
        position = int(rng.integers(MAGIC_BYTES, len(data) - 200))
        damaged[position] ^= 0xFF
        flipped = tmp_path / f"flip{trial}.mcap"
        flipped.write_bytes(bytes(damaged))
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                frames = list(read_frames(flipped))
            except LogError:
                continue  # the flip hit what makes it a deepslam log: named, not guessed
        by_stamp = {f.stamp_ns: f for f in complete}
        for frame in frames:  # what is returned is whole and unchanged
            want = by_stamp[frame.stamp_ns]
            assert np.array_equal(frame.image, want.image) and np.array_equal(frame.T_estimate, want.T_estimate)
            assert np.array_equal(frame.tracks, want.tracks)
        if len(frames) < len(complete):
            assert caught and "whole frames" in str(caught[-1].message)
    huge = tmp_path / "huge.mcap"
    huge.write_bytes(_declare_huge_chunk(bytes(data)))
    started = time.time()
    with pytest.warns(UserWarning, match="over the 64 MiB limit"):
        list(read_frames(huge))
    assert time.time() - started < 10


MAGIC_BYTES = 8


def _declare_huge_chunk(data: bytes) -> bytes:
    """The log with its first chunk declaring 2 GiB uncompressed."""
    import struct

    opcode_chunk = 0x06
    position = MAGIC_BYTES
    while data[position] != opcode_chunk:
        position += 9 + struct.unpack_from("<Q", data, position + 1)[0]
    # chunk record: opcode, length (8), start time (8), end time (8), uncompressed size (8), ...
    size_at = position + 9 + 16
    return data[:size_at] + struct.pack("<Q", 2 * 2**30) + data[size_at + 8 :]


@pytest.mark.parametrize("scale, metres", [("gt", 1e-9), ("map", 1e-6)])
def test_replay_with_the_same_options_reproduces_the_estimate(tmp_path, scale, metres):
    # the log keeps the true first pose as a quaternion: the map's bundle adjustment then starts a rounding
    # away and stops within its convergence tolerance, nanometres from the simulated run's
    original = tmp_path / "classical.mcap"
    config = OdometryConfig(scale=scale)
    simulate(ScenarioConfig(frames=15, seed=5), TrackerConfig("classical"), config, original, progress=False)
    again = tmp_path / "replayed.mcap"
    replay(original, TrackerConfig("classical"), config, again, progress=False)
    first, second = list(read_frames(original)), list(read_frames(again))
    assert len(first) == len(second) == 15
    for a, b in zip(first, second, strict=False):
        assert np.array_equal(a.image, b.image)
        np.testing.assert_allclose(a.T_estimate, b.T_estimate, rtol=0, atol=metres)
    with pytest.raises(ValueError, match="oracle"):
        replay(original, TrackerConfig("oracle"), config, tmp_path / "x.mcap", progress=False)
    size = original.stat().st_size
    with pytest.raises(ValueError, match="overwrite"):
        replay(original, TrackerConfig("classical"), config, tmp_path / "." / "classical.mcap", progress=False)
    assert original.stat().st_size == size and len(list(read_frames(original))) == 15


class _Stopped(Exception):
    pass


def _stop(number, frame):
    raise _Stopped(number)


def test_held_signals_reach_their_handler_at_a_checkpoint_or_the_end_of_the_block():
    previous = signal.signal(signal.SIGTERM, _stop)
    try:
        with held_signals() as held:
            signal.raise_signal(signal.SIGTERM)
            signal.raise_signal(signal.SIGTERM)  # repeats count once
            with held_signals():  # a block inside holds for the one outside
                signal.raise_signal(signal.SIGTERM)
            assert held.received == [signal.SIGTERM] * 3
            with pytest.raises(_Stopped):
                held.checkpoint()
            held.checkpoint()  # delivered already
            signal.raise_signal(signal.SIGTERM)
            reached_the_end = True
        raise AssertionError("the signal held at the end of the block was not delivered")
    except _Stopped:
        assert reached_the_end and signal.getsignal(signal.SIGTERM) is _stop
    finally:
        signal.signal(signal.SIGTERM, previous)


_SIGTERM_AFTER_PYCOLMAP = """
import os, signal, sys, time
signal.signal(signal.SIGTERM, lambda number, frame: sys.exit(143))
from deepslam.interrupts import import_pycolmap
import_pycolmap()  # installs glog's SIGTERM handler from C, as the map's first window adjustment does
os.kill(os.getpid(), signal.SIGTERM)
time.sleep(5)
"""


def test_sigterm_reaches_python_after_pycolmap_is_imported():
    process = subprocess.run([sys.executable, "-c", _SIGTERM_AFTER_PYCOLMAP], capture_output=True, timeout=120)
    assert process.returncode == 143, process.stderr.decode()[-2000:]  # glog's handler ends it at -15


@pytest.mark.slow
@pytest.mark.parametrize(
    "stop, code, word", [(signal.SIGINT, 130, b"interrupted"), (signal.SIGTERM, 143, b"terminated")]
)
def test_ctrl_c_and_sigterm_finish_the_file_cleanly(tmp_path, stop, code, word):
    out = tmp_path / "interrupted.mcap"
    process = _run_until(out, 300_000)
    process.send_signal(stop)
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == code and word in stderr, stderr.decode()[-2000:]
    assert not partial_path(out).exists()
    with open(out, "rb") as f:
        summary = make_reader(f).get_summary()  # a finished file has its summary and footer
    assert summary is not None and summary.statistics.message_count > 0
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no truncation warning
        frames = list(read_frames(out))
    assert len(frames) >= 15


@pytest.mark.slow
def test_sigterm_ends_a_run_of_slow_frames_within_seconds(tmp_path):
    out = tmp_path / "slow.mcap"
    slow = ("--frontend", "magic", "--warp-iterations", "10", "--size", "480", "640")  # about a second a frame
    process = _run_until(out, 1, slow)
    time.sleep(1.5)  # inside a frame
    process.send_signal(signal.SIGTERM)
    started = time.time()
    process.communicate(timeout=60)
    assert process.returncode == 143 and time.time() - started < 5
    assert len(list(read_frames(out))) >= 1  # a finished log


# ends the process with SIGTERM as pycolmap's import finishes, before ``import_pycolmap`` puts Python's handler back:
# the one moment glog's handler, which ends the process at once, is in place
_SIGTERM_AS_PYCOLMAP_LOADS = """
import importlib.abc, importlib.util, os, signal, sys


class SigtermOnImport(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name != "pycolmap":
            return None
        sys.meta_path.remove(self)
        spec = importlib.util.find_spec(name)
        load = spec.loader.exec_module
        spec.loader.exec_module = lambda module: (load(module), os.kill(os.getpid(), signal.SIGTERM))
        return spec


sys.meta_path.insert(0, SigtermOnImport())
from deepslam.cli import main

sys.exit(main(sys.argv[1:]))
"""


def test_a_sigterm_as_pycolmap_loads_never_leaves_a_log_unfinished(tmp_path):
    # glog's SIGTERM handler ends the process at once: a run loads pycolmap before it opens its log (not at its
    # map's first window adjustment, a few frames in)
    out = tmp_path / "run.mcap"
    command = ["run", "--frontend", "oracle", "--frames", "30", "--out", str(out)]
    ended = subprocess.run([sys.executable, "-c", _SIGTERM_AS_PYCOLMAP_LOADS, *command], capture_output=True)
    assert ended.returncode == -signal.SIGTERM, ended.stderr.decode()[-2000:]
    assert not out.exists() and not partial_path(out).exists()


def test_outputs_never_clobber_inputs_or_each_other(oracle_log, tmp_path):
    path, _ = oracle_log
    original = path.read_bytes()
    alias = tmp_path / "alias.mcap"
    os.link(path, alias)  # the same file under another name
    config = OdometryConfig()
    with pytest.raises(ValueError, match="overwrite the input"):
        replay(path, TrackerConfig("classical"), config, alias, progress=False)
    assert path.read_bytes() == original
    busy = tmp_path / "busy.mcap"
    with LogWriter(busy, {}):
        with pytest.raises(LogWriteError, match="being written by another run"):
            LogWriter(busy, {})
    with pytest.raises(LogWriteError, match="is a folder"):
        LogWriter(tmp_path, {})
    pipe = tmp_path / "pipe"
    os.mkfifo(pipe)  # as /dev/null: the finished log renamed onto it would replace it
    with pytest.raises(LogWriteError, match="not a regular file"):
        LogWriter(pipe, {})
    assert pipe.is_fifo() and not partial_path(pipe).exists()
    failed = tmp_path / "failed.mcap"
    failed.write_bytes(b"keep me")
    with pytest.raises(RuntimeError):
        with LogWriter(failed, {}):
            raise RuntimeError("the run failed")
    assert failed.read_bytes() == b"keep me" and partial_path(failed).exists()


def test_report_compares_runs_and_says_what_a_log_lacks(oracle_log, tmp_path):
    import base64

    path, _ = oracle_log
    no_truth = tmp_path / "replayed.mcap"
    replay(
        path, TrackerConfig("classical"), OdometryConfig(scale="plane", plane_distance=2.0), no_truth, progress=False
    )
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(path.read_bytes()[: int(path.stat().st_size * 0.7)])
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not a log")
    out = tmp_path / "report.html"
    assert main(["report", str(path), str(cut), str(junk), "--out", str(out)]) == 0
    page = out.read_text()
    assert "http://" not in page and "https://" not in page  # self-contained: nothing fetched
    images = re.findall(r'src="data:image/png;base64,([^"]+)"', page)
    assert len(images) >= 4 and all(base64.b64decode(i)[:8] == b"\x89PNG\r\n\x1a\n" for i in images)
    assert "junk.mcap: not an MCAP file" in page and "truncated" in page  # said, not hidden
    assert page.count("<tr>") == 3 and ">oracle<" in page  # a row per readable run
    assert main(["report", str(junk), "--out", str(tmp_path / "none.html")]) == 1
    assert not (tmp_path / "none.html").exists()
    twin = tmp_path / "again" / path.name  # the same file name in another folder: told apart by it
    twin.parent.mkdir()
    twin.write_bytes(path.read_bytes())
    assert main(["report", str(path), str(twin), "--out", str(tmp_path / "twins.html")]) == 0
    titles = re.findall(r"<h3>([^<]*)</h3>", (tmp_path / "twins.html").read_text())
    assert titles == [f"{path.parent.name}/{path.stem}", f"again/{path.stem}"]


def test_a_cut_off_log_is_warned_of_once_by_every_command_that_reads_it(oracle_log, tmp_path, capsys):
    path, _ = oracle_log
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(path.read_bytes()[: int(path.stat().st_size * 0.7)])
    commands = {
        "replay": ["replay", str(cut), "--frontend", "classical", "--out", str(tmp_path / "replayed.mcap"), "-q"],
        "report": ["report", str(cut), "--out", str(tmp_path / "report.html")],
        "drift": ["drift", str(cut), "--out", str(tmp_path / "drift")],
    }
    for name, argv in commands.items():
        assert main(argv) == 0, name
        said = capsys.readouterr()
        assert name != "replay" or said.out.startswith("replay (scale: map")  # headlined as what it is
        warned = [line for line in said.err.splitlines() if "truncated" in line]
        assert len(warned) == 1 and "cut.mcap" in warned[0], (name, warned)
        assert re.search(r"read \d+ whole frames?(;|$)", warned[0]), warned[0]


def test_a_loss_counts_its_frames_in_words_that_agree():
    from deepslam.logs.reader import Damage

    assert Damage(["truncated"], 1).report(Path("a.mcap"), 1) == (
        "a.mcap: truncated; read 1 whole frame; 1 damaged frame dropped"
    )
    assert Damage(["truncated"], 2).report(Path("a.mcap"), 0).endswith("read 0 whole frames; 2 damaged frames dropped")


def test_the_report_draws_runs_without_truth_on_their_own_axes_and_legends_outside(oracle_log, monkeypatch):
    from dataclasses import replace as replaced

    from deepslam.backend.evaluation import report

    path, _ = oracle_log
    with_truth = report.load_run(path)
    no_truth = report.Run(
        Path("replayed.mcap"), [replaced(f, T_groundtruth=None) for f in with_truth.frames], with_truth.metadata
    )
    figures = []
    monkeypatch.setattr(report, "_png", lambda fig: figures.append(fig) or "")
    report.trajectory_figures([with_truth, no_truth])
    report.map_figure([with_truth])
    top, *_, own = figures[0].axes
    assert len(figures[0].axes) == 4 and "aligned" in top.get_title() and "no truth" in own.get_title()
    assert [line.get_label() for line in own.get_lines()] == ["replayed estimate"]
    assert not any("replayed" in line.get_label() for line in top.get_lines())
    figures[0].canvas.draw()
    for ax in figures[0].axes + figures[1].axes:  # every legend below its plot, none over the lines
        legend = ax.get_legend()
        assert legend is not None and legend.get_window_extent().y1 <= ax.get_window_extent().y0 + 1
    settings = report._settings(with_truth)
    assert re.search(r"\nodometry\.map\.window +6\n", settings) and re.search(r"\nscenario\.world +plane\n", settings)
    assert "max-height" not in report.STYLE


def test_an_independent_reader_decodes_every_message(oracle_log):
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    from deepslam.logs.schemas import _DEFINITIONS

    path, _ = oracle_log
    typestore = get_typestore(Stores.ROS2_HUMBLE)
    ours = {}
    for name, text in _DEFINITIONS.items():  # our own and Foxglove's types, from the definitions we ship
        if name.split("/")[0] in ("deepslam_msgs", "foxglove_msgs"):
            package, kind = name.split("/")
            ours.update(
                get_types_from_msg(text.replace("foxglove_msgs/", "foxglove_msgs/msg/"), f"{package}/msg/{kind}")
            )
    typestore.register(ours)
    counts: dict[str, int] = {}
    with AnyReader([path], default_typestore=typestore) as reader:
        for connection, _, raw in reader.messages():
            message = reader.deserialize(raw, connection.msgtype)
            counts[connection.topic] = counts.get(connection.topic, 0) + 1
            if connection.topic == "/camera/annotations" and message.points:
                assert len(message.points[0].points) == len(message.points[0].outline_colors)
    assert set(counts) == set(TOPICS) and counts["/camera/image"] == 25


def test_the_foxglove_layout_shows_topics_the_logs_have():
    from importlib.resources import files

    layout = json.loads((files("deepslam.logs") / "foxglove_layout.json").read_text())
    text = json.dumps(layout["configById"])
    mentioned = set(re.findall(r'"(/[a-z_/]+)[."]', text))
    assert mentioned and mentioned <= set(TOPICS), mentioned - set(TOPICS)
    assert set(_panels(layout["layout"])) == set(layout["configById"])


def _panels(node) -> list[str]:
    return [node] if isinstance(node, str) else _panels(node["first"]) + _panels(node["second"])


def test_no_command_writes_over_its_input_or_replaces_a_file_with_nothing(oracle_log, tmp_path):
    path, _ = oracle_log
    log = tmp_path / "run.mcap"
    log.write_bytes(path.read_bytes())
    alias = tmp_path / "alias.mcap"
    os.link(log, alias)
    before = log.read_bytes()
    for out in (log, alias):  # the report onto its input, under its own name or a hard link
        assert main(["report", str(log), "--out", str(out)]) == 1
        assert log.read_bytes() == before
    keep = tmp_path / "keep.mcap"
    keep.write_bytes(b"keep me")
    foreign = tmp_path / "foreign.mcap"
    foreign.write_bytes(b"\x89MCAP0\r\n" + bytes(200))  # an MCAP header and nothing whole after it
    assert main(["recover", str(foreign), "--out", str(keep)]) == 1  # zero frames: an error, keep untouched
    assert keep.read_bytes() == b"keep me" and not partial_path(keep).exists()
    report = tmp_path / "report.html"
    assert main(["report", str(log), "--out", str(report)]) == 0 and "<html>" in report.read_text()
    assert not partial_path(report).exists()


def test_a_log_that_finished_between_another_writers_open_and_lock_is_not_truncated(tmp_path, monkeypatch):
    import fcntl

    out = tmp_path / "run.mcap"
    first = LogWriter(out, {"run": 1})
    real_flock, renamed = fcntl.flock, []

    def flock_after_the_first_run_finished(descriptor, operation):
        if not renamed:  # the first run finishes (renames its partial, releases its lock) before our lock
            renamed.append(True)
            first.close()
        return real_flock(descriptor, operation)

    monkeypatch.setattr(fcntl, "flock", flock_after_the_first_run_finished)
    second = LogWriter(out, {"run": 2})
    monkeypatch.setattr(fcntl, "flock", real_flock)
    second.close(complete=False)
    assert read_metadata(out)["run"] == 1  # the finished log is whole


def _with_bomb_chunk(data: bytes) -> bytes:
    """The log with its second chunk's records (the first defines the channels) replaced by a 64 KB zstd
    frame of 2 GiB of zeros, the chunk still declaring 1,000 bytes uncompressed."""
    import struct

    import zstandard

    compressor = zstandard.ZstdCompressor(level=1).compressobj(size=2 * 2**30)  # the header promises 2 GiB
    bomb = b"".join([compressor.compress(bytes(2**24)) for _ in range(128)] + [compressor.flush()])
    position, chunks = MAGIC_BYTES, 0
    while chunks < 2:  # to the second chunk record
        chunks += data[position] == 0x06
        if chunks < 2:
            position += 9 + struct.unpack_from("<Q", data, position + 1)[0]
    start, end = struct.unpack_from("<QQ", data, position + 9)
    body = struct.pack("<QQQI", start, end, 1000, 0) + struct.pack("<I", 4) + b"zstd"
    body += struct.pack("<Q", len(bomb)) + bomb
    after = position + 9 + struct.unpack_from("<Q", data, position + 1)[0]
    return data[:position] + b"\x06" + struct.pack("<Q", len(body)) + body + data[after:]


def test_a_chunk_that_lies_about_its_size_is_skipped_fast_with_bounded_memory(oracle_log, tmp_path):
    path, _ = oracle_log
    bomb = tmp_path / "bomb.mcap"
    bomb.write_bytes(_with_bomb_chunk(path.read_bytes()))
    code = (
        "import resource, sys, time, warnings\nfrom deepslam.logs.reader import read_frames\n"
        "warnings.simplefilter('always')\nstarted = time.time()\n"
        "with warnings.catch_warnings(record=True) as caught:\n    frames = len(list(read_frames(sys.argv[1])))\n"
        "print(frames, time.time() - started, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3)\n"
        "print(caught[-1].message if caught else '')"
    )
    runs = [subprocess.run([sys.executable, "-c", code, str(p)], capture_output=True, text=True) for p in (path, bomb)]
    (clean, _, clean_mb), (frames, seconds, bomb_mb) = ([float(v) for v in r.stdout.split()[:3]] for r in runs)
    assert 0 < frames < clean and seconds < 5 and bomb_mb - clean_mb < 300, runs[1].stdout
    assert "chunk 2" in runs[1].stdout and "declares 1000 bytes but holds more" in runs[1].stdout


def test_a_flipped_byte_in_the_metadata_is_reported(oracle_log, tmp_path):
    path, _ = oracle_log
    data = path.read_bytes()
    assert read_metadata(path)["scenario"]["seed"] == 3
    flipped = tmp_path / "flipped.mcap"
    flipped.write_bytes(data.replace(b'"seed": 3', b'"seed": 7', 1))
    with pytest.warns(UserWarning, match="metadata record does not match its checksum"):
        assert read_metadata(flipped)["scenario"]["seed"] == 7
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read_metadata(path)  # an intact record says nothing


def test_a_full_disk_names_the_partial_log_and_how_to_recover_it(tmp_path, monkeypatch, capsys):
    import errno

    out = tmp_path / "run.mcap"
    real_write = LogWriter._write

    def full_after_three_frames(self, frame):
        if self.frames >= 3:
            raise OSError(errno.ENOSPC, "No space left on device")
        real_write(self, frame)

    monkeypatch.setattr(LogWriter, "_write", full_after_three_frames)
    code = main(["run", "-q", "--frontend", "oracle", "--frames", "8", "--out", str(out)])
    error = capsys.readouterr().err
    assert code == 1 and f"{out}.partial: No space left on device" in error and "deepslam recover" in error, error
    assert not out.exists() and len(error.strip().splitlines()) == 1
    assert len(list(read_frames(partial_path(out)))) == 3  # what was written before can be recovered
