"""deepslam: simulated camera runs, replays of recorded data, drift, reports, evaluations and training
of the system of "Toward Geometric Deep SLAM" (DeTone et al. 2017). `deepslam COMMAND --help` explains a
command and every option, with its default."""

from __future__ import annotations

import argparse
import logging
import math
import os
import signal
import sys
import warnings
from pathlib import Path

from deepslam.errors import InputError
from deepslam.options import add_options, from_args, number_type

log = logging.getLogger("deepslam")
MAX_SCALE_DRIFT = 2.0  # a run whose scale drifts more than this (or under its inverse) is warned of


class _Parser(argparse.ArgumentParser):
    """An argument parser whose usage errors are one line naming the command, then exit 2."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {' '.join(message.split())} (see {self.prog} --help)\n")


class _Formatter(argparse.ArgumentDefaultsHelpFormatter, argparse.RawDescriptionHelpFormatter):
    """Help that shows each default once, as it would be typed (values apart by spaces; a flag on or off), and
    keeps the descriptions' line breaks. No default is shown where there is none or where the text already says
    it."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        default = action.default
        if "default" in text or default is None or default == argparse.SUPPRESS or action.required:
            return text
        if isinstance(default, bool):
            shown = "on" if default else "off"
        else:
            shown = " ".join(map(str, default)) if isinstance(default, (tuple, list)) else str(default)
        return f"{text} (default: {shown.replace('%', '%%')})"


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("deepslam")
    except PackageNotFoundError:
        return "unknown (not installed)"


# ---------------------------------------------------------------- handlers: parse -> library call -> print


def _train_magicpoint(args: argparse.Namespace) -> None:
    from deepslam.frontend.training.magicpoint import TrainConfig, run

    run(args.out or Path(f"runs/magicpoint_{args.variant}"), _config(args, TrainConfig))


def _train_magicpoint_ha(args: argparse.Namespace) -> None:
    from deepslam.frontend.training.adaptation import AdaptConfig, run

    run(args.out, _config(args, AdaptConfig))


def _train_magicwarp(args: argparse.Namespace) -> None:
    from deepslam.frontend.config import MagicWarpConfig
    from deepslam.frontend.training.magicwarp import TrainConfig, run

    run(args.out, _config(args, TrainConfig), _config(args, MagicWarpConfig))


def _export(args: argparse.Namespace) -> None:
    from deepslam.frontend.training.loop import export_weights

    state = export_weights(args.checkpoint, args.out)
    log.info(f"wrote {args.out} (step {state['step']}, {args.out.stat().st_size / 1e6:.2f} MB)")


def _file_path(text: str) -> Path:
    """An output that names a file (argparse type): refused where it ends in a path separator, as a folder's name
    may (a ``Path`` drops the separator, and the file would take the folder's name)."""
    if text.endswith(("/", os.sep)):
        raise argparse.ArgumentTypeError(f"{text} ends in {text[-1]}, as a folder does; give a file name")
    return Path(text)


def _check_folder(folder: Path) -> None:
    """Fail before any work starts unless results can be written into ``folder`` (made if missing)."""
    if folder.exists() and not folder.is_dir():
        raise _UsageError(f"--out {folder} is a file, not a folder")
    existing = folder
    while not existing.exists():
        existing = existing.parent
    if not os.access(existing, os.W_OK | os.X_OK):
        raise _UsageError(f"--out {folder}: cannot write under {existing}")


def _save(result, out: Path) -> None:
    """Print a result's table and write it, as .txt and .json, and its plots into the folder ``out``."""
    print(result.table())
    for path in result.save(out):
        log.info(f"wrote {path}")


def _eval_detector(args: argparse.Namespace) -> None:
    from deepslam.frontend.config import EXTRACTION_PRESETS
    from deepslam.frontend.evaluation import detector as ev

    _check_folder(args.out)

    shapes = EXTRACTION_PRESETS["shapes"]
    chosen = _detectors(args.detectors, args.weights, threshold=shapes.threshold, border=shapes.border)
    _save(ev.report(chosen, args.per_category, args.sweep_per_category, args.seed, _workers(args)), args.out)


def _eval_warp(args: argparse.Namespace) -> None:
    from deepslam.frontend.evaluation import warp as ev
    from deepslam.frontend.magicwarp import MagicWarp

    _check_folder(args.out)

    _save(
        ev.breakdown_table(MagicWarp.pretrained(args.weights), args.runs, args.seed, workers=_workers(args)), args.out
    )


def _eval_realimages(args: argparse.Namespace) -> None:
    from deepslam.frontend.evaluation import detector as ev

    _check_folder(args.out)

    detectors = _detectors(args.detectors, args.weights)
    _save(
        ev.static_repeatability(detectors, args.frames, args.seed, jitter_px=args.jitter, workers=_workers(args)),
        args.out,
    )


def _workers(args: argparse.Namespace):
    from deepslam.parallel import Workers

    return Workers(args.jobs, args.ray)


def _detectors(names: list[str] | None, weights: list[Path] | None = None, **extraction) -> dict:
    """The detectors ``names`` picks (all when None), and MagicPoint from each of ``weights``."""
    from deepslam.frontend.evaluation.detector import available_detectors

    detectors = available_detectors(**extraction, weights=tuple(weights or ()))
    unknown = set(names or []) - set(detectors)
    if unknown:
        raise _UsageError(f"unknown or unavailable detectors {sorted(unknown)}; available: {', '.join(detectors)}")
    picked = {str(path) for path in weights or ()} | set(names or detectors)
    return {name: d for name, d in detectors.items() if name in picked}


def _eval_pipeline(args: argparse.Namespace) -> None:
    from deepslam.backend.evaluation.sweep import SweepConfig, pipeline_matrix
    from deepslam.frontend.config import TrackerConfig

    _check_folder(args.out)

    _save(pipeline_matrix(_config(args, SweepConfig), _config(args, TrackerConfig), workers=_workers(args)), args.out)


def _bench(args: argparse.Namespace) -> None:
    _check_folder(args.out)
    if args.target == "pipeline":
        from deepslam.backend.evaluation.bench import bench_pipeline
        from deepslam.frontend.config import TrackerConfig

        _save(bench_pipeline(args.frames, tracker_config=_config(args, TrackerConfig), rounds=args.rounds), args.out)
        return
    from deepslam.frontend.evaluation import bench

    _save(bench.bench_detector(args.repeats) if args.target == "detector" else bench.bench_warp(args.repeats), args.out)


def _print_summary(summary: dict, scale: str, command: str = "run") -> None:
    """The figures of a ``command`` (run or replay): what needs no truth, then the drift where there was truth."""
    meaning = {"map": " = a local map's, its first baseline from the truth where there is any, else 1",
               "gt": " = ground-truth step lengths", "plane": " = known distance to the dominant plane",
               "none": ": up to scale, drift after Sim(3) alignment only"}[scale]  # fmt: skip
    print(f"{command} (scale: {scale}{meaning})")
    for key, value in summary.items():
        print(f"  {key:<20} {value:.4f}" if isinstance(value, float) else f"  {key:<20} {value}")
    if "ate_sim3" in summary:
        print("  (ate: RMSE of positions after alignment, m; rpe: mean over consecutive frames, m and deg)")
    if "track_error_px" in summary:
        print("  (*_error_px: medians against the simulator's truth)")
    drifted = summary.get("scale_drift", 1.0)
    if math.isnan(drifted):
        print("  (scale_drift: nan, as it needs 8 frames and a camera that moved in the first and last quarter)")
    elif not 1 / MAX_SCALE_DRIFT <= drifted <= MAX_SCALE_DRIFT:
        log.warning(
            f"deepslam: warning: the estimate's scale drifted {drifted:.2f}x against the truth (the last quarter's "
            "path over the first's): its later steps are measured at another scale than its first"
        )


def _run(args: argparse.Namespace) -> None:
    from deepslam.backend.config import OdometryConfig
    from deepslam.backend.evaluation.runs import simulate
    from deepslam.frontend.config import TrackerConfig
    from deepslam.sim.scenario import ScenarioConfig

    configs = _config(args, ScenarioConfig), _config(args, TrackerConfig), _config(args, OdometryConfig)
    result = simulate(*configs, args.out, {"version": _version()})
    _print_summary(result["summary"], result["scale"])
    final = result["final_ate_se3"]
    print(f"  (online estimates, as logged; the final trajectory, refined by later frames, has ATE SE3 {final:.4f})")
    log.info(f"wrote {args.out}")


def _replay(args: argparse.Namespace) -> None:
    from deepslam.backend.config import OdometryConfig
    from deepslam.backend.evaluation.runs import replay
    from deepslam.frontend.config import TrackerConfig
    from deepslam.inputs.source import SourceOptions
    from deepslam.inputs.video import VIDEO_SUFFIXES

    _check_inputs([args.input])
    configs = _config(args, TrackerConfig), _config(args, OdometryConfig)
    sources = _config(args, SourceOptions)
    if args.input.suffix.lower() in VIDEO_SUFFIXES and sources.calibration is None:
        raise _UsageError(f"{args.input}: a video carries no calibration; give --calibration FILE")
    if args.scale == "plane" and args.plane_distance is None:
        raise _UsageError("--scale plane needs --plane-distance M, the first camera's distance to the dominant plane")
    result = replay(args.input, *configs, args.out, {"version": _version()}, source_options=sources)
    _print_summary(result["summary"], result["scale"], "replay")
    log.info(f"wrote {args.out}")


def _check_inputs(paths: list[Path]) -> None:
    """A missing input is a usage error (exit 2), found before any work starts."""
    for path in paths:
        if not path.exists():
            raise _UsageError(f"{path}: no such file or folder")


def _drift(args: argparse.Namespace) -> None:
    from deepslam.backend.evaluation import analysis
    from deepslam.files import distinct_names

    _check_inputs(args.logs)
    _check_folder(args.out)
    if (args.out / "drift.txt").exists():
        raise _UsageError(f"--out {args.out} holds an earlier drift's results; give another folder or remove them")
    _save(analysis.analyse(args.logs, args.delta, args.limit), args.out)
    names = distinct_names(args.logs)
    for path in (
        [path for run in args.logs for path in analysis.export_tum(run, args.out, names[str(run)])] if args.tum else []
    ):
        log.info(f"wrote {path}")


def _report(args: argparse.Namespace) -> None:
    from deepslam.backend.evaluation.report import write_report

    _check_inputs(args.logs)
    if args.out.is_dir():
        raise _UsageError(f"--out {args.out} is a folder; give a file name such as report.html")
    for line in write_report(args.logs, args.out):
        log.warning(f"deepslam: warning: {line}")
    log.info(f"wrote {args.out}")


def _recover(args: argparse.Namespace) -> None:
    from deepslam.logs.recover import recover

    _check_inputs([args.log])
    frames, damage = recover(args.log, args.out)
    lost = f" ({damage.report(args.log, frames)})" if damage.problems or damage.dropped_frames else ""
    print(f"recovered {frames} whole frames of {args.log} into {args.out}{lost}")


# ---------------------------------------------------------------- the parser


class _UsageError(InputError):
    """Bad options found after parsing: exit 2, as argparse's own."""


def _config(args: argparse.Namespace, config: type):
    try:
        return from_args(config, args)
    except ValueError as error:
        raise _UsageError(str(error)) from None


def _command(commands, name: str, text: str, func, *configs: type, exclude: tuple[str, ...] = ()):
    """A sub-command with the options of ``configs`` (the dataclasses' documented fields)."""
    parser = commands.add_parser(name, help=text, description=text, formatter_class=_Formatter, parents=[_COMMON])
    for config in configs:
        add_options(parser, config, exclude)
    parser.set_defaults(func=func, parser=parser)
    return parser


_COMMON = argparse.ArgumentParser(add_help=False)
_COMMON.add_argument("-q", "--quiet", action="store_true", help="print results and errors only (no progress, no notes)")
_COMMON.add_argument("-v", "--verbose", action="store_true", help="also print debugging notes")


def _train_commands(commands, detailed: bool) -> None:
    """``train`` and its networks; their options (whose configs import torch) only when ``detailed``."""
    train = commands.add_parser("train", help="train a network (resumes from its last checkpoint)")
    if not detailed:
        return
    from deepslam.frontend.config import MagicWarpConfig
    from deepslam.frontend.training import magicpoint, magicwarp
    from deepslam.frontend.training.adaptation import AdaptConfig

    nets = train.add_subparsers(dest="network", required=True, metavar="NETWORK")
    point = _command(
        nets, "magicpoint", "train MagicPoint S or L on Synthetic Shapes", _train_magicpoint, magicpoint.TrainConfig
    )
    point.add_argument("--out", type=Path, default=None, help="checkpoint folder (default: runs/magicpoint_VARIANT)")
    adapt = _command(
        nets,
        "magicpoint-ha",
        "train MagicPoint S-HA on real photographs by homographic adaptation (labels and rounds resume too)",
        _train_magicpoint_ha,
        AdaptConfig,
    )
    adapt.add_argument("--out", type=Path, default=Path("runs/magicpoint_S-HA"), help="folder of the rounds")
    warp = _command(
        nets,
        "magicwarp",
        "train MagicWarp on rendered point-cloud pairs",
        _train_magicwarp,
        magicwarp.TrainConfig,
        MagicWarpConfig,
    )
    warp.add_argument("--out", type=Path, default=Path("runs/magicwarp"), help="checkpoint folder")
    export = nets.add_parser(
        "export",
        help="strip a training checkpoint down to the weights that ship",
        formatter_class=_Formatter,
        parents=[_COMMON],
    )
    export.add_argument("checkpoint", type=Path, help="a training checkpoint, e.g. runs/magicpoint_S_ft/best.pt")
    export.add_argument(
        "out", type=_file_path, help="where to write the weights, e.g. frontend/weights/magicpoint_S.pt"
    )
    export.set_defaults(func=_export, parser=export)


def _pipeline_commands(commands) -> None:
    from deepslam.backend.config import OdometryConfig
    from deepslam.backend.evaluation.config import DriftConfig
    from deepslam.frontend.config import TrackerConfig
    from deepslam.inputs.source import SourceOptions
    from deepslam.sim.scenario import ScenarioConfig

    run = _command(
        commands,
        "run",
        "run a simulated trajectory end to end, log it to MCAP, print its drift",
        _run,
        ScenarioConfig,
        TrackerConfig,
        OdometryConfig,
    )
    run.add_argument("--out", type=_file_path, default=Path("out/run.mcap"), help="MCAP log to write")
    replay = _command(
        commands,
        "replay",
        "run the pipeline on recorded data into a new log: a deepslam log, a ROS 2 bag, a TUM RGB-D or an "
        "EuRoC/ASL folder, or a video file",
        _replay,
        TrackerConfig,
        OdometryConfig,
        SourceOptions,
    )
    replay.add_argument(
        "input",
        type=Path,
        help="a deepslam log, a ROS 2 bag (.mcap file or rosbag2 folder), a TUM or EuRoC folder, or a video file",
    )
    replay.add_argument("--out", type=_file_path, default=Path("out/replay.mcap"), help="MCAP log to write")
    for parser in (run, replay):
        parser.set_defaults(runs_pipeline=True)
    report = _command(commands, "report", "one self-contained HTML page comparing runs from their logs", _report)
    report.add_argument("logs", type=Path, nargs="+", help="MCAP logs written by deepslam run or replay")
    report.add_argument("--out", type=_file_path, default=Path("out/report.html"), help="the HTML file to write")
    recover = _command(
        commands,
        "recover",
        "write every whole frame of a killed (OUT.partial) or damaged log as a finished file",
        _recover,
    )
    recover.add_argument("log", type=Path, help="the log to recover, e.g. out/run.mcap.partial")
    recover.add_argument("--out", type=_file_path, required=True, help="the finished log to write")
    drift = _command(commands, "drift", "ATE/RPE/final drift of logs, side by side, with plots", _drift)
    drift.add_argument("logs", type=Path, nargs="+", help="MCAP logs holding /groundtruth/pose and /estimate/pose")
    add_options(drift, DriftConfig)
    drift.add_argument(
        "--out", type=Path, default=Path("out/drift"),
        help="folder for drift.txt, drift.json, drift.png (and the TUM files); never one with an earlier drift's",
    )  # fmt: skip
    drift.add_argument("--tum", action="store_true", help="also export both trajectories in TUM format")


def _eval_commands(commands) -> None:
    from deepslam.backend.evaluation.config import SweepConfig
    from deepslam.frontend.config import TrackerConfig
    from deepslam.frontend.evaluation.config import DetectorEvalConfig, RealImagesConfig, WarpEvalConfig
    from deepslam.parallel import Workers

    evaluate = commands.add_parser("eval", help="the paper's evaluations, and the pipeline's drift over a sweep")
    evals = evaluate.add_subparsers(dest="experiment", required=True, metavar="EXPERIMENT")
    detector_names = (
        "MagicPointS, MagicPointL, MagicPointS-HA, MagicPointS-x4 = S with four grid shifts, "
        "MagicPointS-2x = S on the image enlarged 2x with two grid shifts, FAST, Harris, Shi"
    )
    detector = _command(
        evals, "detector", "Synthetic Shapes mAP/MLE table, per category, noise sweeps", _eval_detector,
        DetectorEvalConfig,
    )  # fmt: skip
    detector.add_argument("--detectors", nargs="+", metavar="NAME", help=f"evaluate only these ({detector_names})")
    warp = _command(
        evals,
        "warp",
        "MagicWarp 90%% breakdown-point table (nearest neighbour, RANSAC, MagicWarp raw, "
        "applied twice, refined, given image B without its spurious points) and plots",
        _eval_warp,
        WarpEvalConfig,
    )
    warp.add_argument("--weights", type=Path, help="MagicWarp weights or a checkpoint (default: the shipped ones)")
    real = _command(
        evals,
        "realimages",
        "repeatability and localisation error on real photographs under changing light",
        _eval_realimages,
        RealImagesConfig,
    )
    real.add_argument("--detectors", nargs="+", metavar="NAME", help=f"evaluate only these ({detector_names})")
    for parser in (detector, real):
        parser.add_argument(
            "--weights",
            type=Path,
            nargs="+",
            metavar="PATH",
            help="also evaluate MagicPoint from these weights files or training checkpoints, each named by its path "
            "(one pass, S-HA's own sub-pixel peaks)",
        )
    sweep = _command(
        evals,
        "pipeline",
        "drift over worlds x front-ends x noise, averaged over seeds",
        _eval_pipeline,
        SweepConfig,
        TrackerConfig,
        exclude=("frontend",),
    )
    sweep.set_defaults(runs_pipeline=True)
    for parser in evals.choices.values():
        parser.add_argument("--out", type=Path, default=Path("out/eval"), help="folder for the .txt, .json and plots")
        add_options(parser, Workers)
        parser.add_argument(
            "--ray", default=None, metavar="ADDRESS",
            help="run the pieces on the Ray cluster at ADDRESS, as `ray start --head` printed it (needs pip install "
            "-e '.[ray]'); a cluster listens on every network interface of its machines, so start it on purpose "
            "(--jobs N runs local processes instead)",
        )  # fmt: skip


def _bench_commands(commands) -> None:
    from deepslam.backend.evaluation.config import PipelineBenchConfig
    from deepslam.frontend.config import BENCH_REPEATS, TrackerConfig

    bench = commands.add_parser("bench", help="timings on one CPU thread, beside the paper's")
    targets = bench.add_subparsers(dest="target", required=True, metavar="TARGET")
    for target, text in (
        ("detector", "MagicPoint forward passes (BatchNorm folded) and point extraction"),
        ("warp", "MagicWarp forward pass (BatchNorm folded)"),
    ):
        sub = _command(targets, target, text, _bench)
        sub.add_argument(
            "--repeats",
            type=number_type(int, 1, 100_000),
            default=BENCH_REPEATS,
            help="timed repetitions (median reported) (at most 100000)",
        )
        sub.add_argument("--out", type=Path, default=Path("out/bench"), help="folder for the .txt and .json")
    pipeline = _command(
        targets,
        "pipeline",
        "per-frame time of every pipeline stage (no rendering)",
        _bench,
        PipelineBenchConfig,
        TrackerConfig,
    )
    pipeline.add_argument("--out", type=Path, default=Path("out/bench"), help="folder for the .txt and .json")
    pipeline.set_defaults(runs_pipeline=True)


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    """The command line; with ``argv``, the training options only where it asks to train, so that every
    other command and ``--help`` start without torch (without ``argv``: all of it)."""
    words = ["train"] if argv is None else [word for word in argv if not word.startswith("-")]
    parser = _Parser(prog="deepslam", description=__doc__, formatter_class=_Formatter)
    parser.add_argument("--version", action="version", version=f"deepslam {_version()}")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    _train_commands(commands, detailed=words[:1] == ["train"])
    _pipeline_commands(commands)
    _eval_commands(commands)
    _bench_commands(commands)
    return parser


def _configure_logging(args: argparse.Namespace) -> None:
    """Notes to standard error at the level -q / -v ask for; Python warnings (a damaged log, say) as one
    line each, each said once however often the command meets it (a log read twice)."""
    level = logging.WARNING if args.quiet else logging.DEBUG if args.verbose else logging.INFO
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("%(message)s"))
    log.handlers[:] = [handler]
    log.setLevel(level)
    log.propagate = False
    said: set[str] = set()

    def show(message, category, *_, **__) -> None:
        if str(message) not in said:
            said.add(str(message))
            log.warning(f"deepslam: warning: {message}")

    warnings.showwarning = show


class Terminated(KeyboardInterrupt):
    """SIGTERM, handled like Ctrl-C: logs in progress are finished."""


def _terminate(number, frame) -> None:
    raise Terminated()


def main(argv: list[str] | None = None) -> int:
    """Run the command; exit status 0, 1 for a runtime error, 2 for a usage error, 130 on Ctrl-C and
    143 on SIGTERM."""
    argv = sys.argv[1:] if argv is None else argv
    parser = build_parser(argv)
    args, unknown = parser.parse_known_args(argv)
    if unknown:  # named by the command they were given to
        getattr(args, "parser", parser).error(f"unrecognized arguments: {' '.join(unknown)}")
    _configure_logging(args)
    if getattr(args, "runs_pipeline", False):  # before Python's SIGTERM handler is in place (``import_pycolmap``)
        from deepslam.interrupts import import_pycolmap

        import_pycolmap()
    signal.signal(signal.SIGTERM, _terminate)
    import cv2
    import torch

    threads = getattr(args, "threads", 1)
    torch.set_num_threads(threads)  # small networks: one thread is fastest (the paper's set-up)
    cv2.setNumThreads(threads)
    return _ended(_run_command(args, parser))


def _run_command(args: argparse.Namespace, parser: argparse.ArgumentParser) -> int:
    """The command's exit status, its errors said in one line."""
    try:
        args.func(args)
    except _UsageError as error:
        getattr(args, "parser", parser).error(str(error))
    except BrokenPipeError:  # the reader of our output went away (`deepslam ... | head`)
        sys.stdout = open(os.devnull, "w")  # nothing more reaches it: do not fail at exit
        return 0
    except OSError as error:
        where = f"{error.filename}: " if error.filename else ""
        print(f"deepslam: error: {where}{error.strerror or error}", file=sys.stderr)
        return 1
    except (ValueError, RuntimeError) as error:  # one line, also for gtsam's and OpenCV's many-line messages
        print(f"deepslam: error: {' '.join(str(error).split())}", file=sys.stderr)
        return 1
    except KeyboardInterrupt as interrupt:
        print(f"deepslam: {'terminated' if isinstance(interrupt, Terminated) else 'interrupted'}", file=sys.stderr)
        return 143 if isinstance(interrupt, Terminated) else 130
    return 0


def _ended(status: int) -> int:
    """``status``; a rank of a torchrun process group (``deepslam train`` under torchrun) exits with it at once
    instead, its output flushed, without Python's shutdown: torch's gloo threads may still be letting go of a
    finished collective's tensors then, which aborts the process (pytorch/pytorch#190489), and neither the end
    of training nor ``destroy_process_group`` waits for them."""
    distributed = sys.modules.get("torch.distributed")
    if distributed is None or not distributed.is_available() or not distributed.is_initialized():
        return status
    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(status)


if __name__ == "__main__":
    sys.exit(main())
