"""`deepslam`: one entry point wiring the packages; every command's logic lives in them."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path


def _train_magicwarp(args: argparse.Namespace) -> None:
    from deepslam.frontend.magicwarp import MagicWarpConfig
    from deepslam.frontend.training.magicwarp import TrainConfig, run

    config = TrainConfig(
        iterations=args.iterations,
        batch=args.batch,
        lr=args.lr,
        seed=args.seed,
        motion_start=args.motion_start,
        motion_ramp=args.motion_ramp,
        motion_max=args.motion_max,
        geometry_weights=tuple(args.geometry_weights),
        homography=tuple(args.homography),
        loss_weighting=args.loss_weighting,
        cauchy=args.cauchy,
        max_extra=args.max_extra,
        clean_a_share=args.clean_a_share,
        validate_every=args.validate_every,
        threads=args.threads,
        ema=args.ema,
        init=args.init,
    )
    shape = {"widths": tuple(args.widths) if args.widths else None, "hidden": args.hidden, "blocks": args.blocks}
    run(args.out, config, MagicWarpConfig(**{name: value for name, value in shape.items() if value is not None}))


def _train_magicpoint(args: argparse.Namespace) -> None:
    from deepslam.frontend.training.magicpoint import TrainConfig, run

    run(
        args.out or Path(f"runs/magicpoint_{args.variant}"),
        TrainConfig(
            variant=args.variant,
            iterations=args.iterations,
            batch=args.batch,
            lr=args.lr,
            seed=args.seed,
            validate_every=args.validate_every,
            threads=args.threads,
            clean_share=args.clean_share,
            validation_per_category=args.validation_per_category,
            ema=args.ema,
            init=args.init,
        ),
    )


def _export(args: argparse.Namespace) -> None:
    from deepslam.frontend.training.loop import export_weights

    if not args.checkpoint.exists():
        raise FileNotFoundError(f"no checkpoint at {args.checkpoint}")
    state = export_weights(args.checkpoint, args.out)
    print(f"wrote {args.out} (step {state['step']}, {args.out.stat().st_size / 1e6:.2f} MB)")


def _report(out: Path, name: str, result: dict, lines: list[str], plots) -> None:
    """Print a result's table, save it as JSON (and its plots) under ``out``."""
    import json

    print("\n".join(lines))
    (out / f"{name}.json").write_text(json.dumps(result, indent=1))
    for path in [*(plots(result, out) if plots else []), out / f"{name}.json"]:
        print(f"wrote {path}")


def _eval_detector(args: argparse.Namespace) -> None:
    from deepslam.frontend.evaluation import detector as ev

    if args.per_category < 1 or args.sweep_per_category < 1:
        raise ValueError("--per-category and --sweep-per-category must be at least 1")
    detectors = ev.available_detectors(**ev.SHAPES_EXTRACTION)
    unknown = set(args.detectors or []) - set(detectors)
    if unknown:
        raise ValueError(f"unknown or unavailable detectors {sorted(unknown)}; available: {', '.join(detectors)}")
    args.out.mkdir(parents=True, exist_ok=True)
    chosen = {name: d for name, d in detectors.items() if not args.detectors or name in args.detectors}
    result = ev.report(chosen, args.per_category, args.sweep_per_category, args.seed)
    _report(args.out, "detector", result, ev.table_lines(result) + [""] + ev.category_lines(result), ev.save_plots)


def _eval_warp(args: argparse.Namespace) -> None:
    from deepslam.frontend.evaluation import warp as ev
    from deepslam.frontend.magicwarp import MagicWarp

    if args.runs < 1:
        raise ValueError("--runs must be at least 1")
    args.out.mkdir(parents=True, exist_ok=True)
    result = ev.breakdown_table(MagicWarp.pretrained(args.weights), args.runs, args.seed)
    _report(args.out, "warp", result, ev.table_lines(result), ev.save_plots)


def _eval_realimages(args: argparse.Namespace) -> None:
    from deepslam.frontend.evaluation import detector as ev

    if args.frames < 2:
        raise ValueError("--frames must be at least 2")
    if args.jitter < 0:
        raise ValueError("--jitter must be at least 0")
    args.out.mkdir(parents=True, exist_ok=True)
    result = ev.static_repeatability(ev.available_detectors(), args.frames, args.seed, jitter_px=args.jitter)
    _report(
        args.out,
        f"realimages_jitter{args.jitter:g}" if args.jitter else "realimages",
        result,
        ev.static_lines(result),
        None,
    )


def _eval_pipeline(args: argparse.Namespace) -> None:
    from deepslam.backend.evaluation.runs import matrix_lines, pipeline_matrix

    rows = pipeline_matrix(
        tuple(args.worlds),
        tuple(args.frontends),
        tuple(args.noise),
        args.frames,
        tuple(range(args.seeds)),
        args.scale,
        args.trajectory,
        args.detector_scale,
    )
    args.out.mkdir(parents=True, exist_ok=True)
    _report(args.out, "pipeline", {"rows": rows}, matrix_lines(rows), None)


def _bench(args: argparse.Namespace) -> None:
    if args.target == "pipeline":
        from deepslam.backend.evaluation.runs import bench_pipeline

        for name, value in bench_pipeline(args.frames, detector_scale=args.detector_scale).items():
            print(f"  {name:<24} {value:8.2f} {'' if name == 'fps' else 'ms'}")
        return
    from deepslam.frontend.evaluation import bench

    rows = bench.bench_detector(args.repeats) if args.target == "detector" else bench.bench_warp(args.repeats)
    for row in rows:
        print("  " + "  ".join(f"{k}={v:.2f}" if isinstance(v, float) else f"{k}={v}" for k, v in row.items()))


def _odometry_config(args: argparse.Namespace):
    from deepslam.backend.odometry import OdometryConfig

    return OdometryConfig(
        method=args.method,
        scale=args.scale,
        plane_distance=args.plane_distance,
        keyframe_parallax=args.keyframe_parallax,
    )


def _tracker_options(args: argparse.Namespace) -> dict:
    if args.frontend == "oracle":
        if args.oracle_noise < 0:
            raise ValueError("--oracle-noise must be at least 0")
        return {"oracle_noise_px": args.oracle_noise}
    if args.frontend != "magic":
        return {}
    return {
        "iterations": args.warp_iterations,
        "ransac": args.ransac,
        "refine": not args.no_refine,
        "detector_scale": args.detector_scale,
        **({"carry": False} if args.no_carry else {}),
    }


def _print_drift(drift: dict, scale: str) -> None:
    print(
        f"drift (scale: {scale}{' = ground-truth step lengths' if scale == 'gt' else ' = known distance to the dominant plane'})"
    )
    for key, value in drift.items():
        print(f"  {key:<16} {value:.4f}" if isinstance(value, float) else f"  {key:<16} {value}")


def _run(args: argparse.Namespace) -> None:
    from deepslam.backend.evaluation.runs import simulate
    from deepslam.sim.scenario import ScenarioConfig

    scenario = ScenarioConfig(
        world=args.world,
        trajectory=args.trajectory,
        frames=args.frames,
        speed=args.speed,
        fps=args.fps,
        noise=args.noise,
        lighting=args.lighting,
        seed=args.seed,
        size=tuple(args.size),
    )
    result = simulate(
        scenario, args.frontend, _odometry_config(args), args.out, {"version": _version()}, **_tracker_options(args)
    )
    _print_drift(result["drift"], result["scale"])
    print(f"  (online estimates, as logged; the final smoothed graph has ATE SE3 {result['smoothed_ate_se3']:.4f})")
    print(f"wrote {args.out}")


def _replay(args: argparse.Namespace) -> None:
    from deepslam.backend.evaluation.runs import replay

    result = replay(
        args.log, args.frontend, _odometry_config(args), args.out, {"version": _version()}, **_tracker_options(args)
    )
    if result["drift"] is not None:
        _print_drift(result["drift"], result["scale"])
    print(f"wrote {args.out}")


def _drift(args: argparse.Namespace) -> None:
    from deepslam.backend.evaluation import analysis

    results = analysis.analyse(args.logs, args.delta)
    print("\n".join(analysis.table_lines(results)))
    for path in analysis.save_plots(args.logs, args.out, args.delta):
        print(f"wrote {path}")
    if args.tum:
        for log in args.logs:
            for path in analysis.export_tum(log, args.out):
                print(f"wrote {path}")


def _version() -> str:
    from importlib.metadata import version

    return version("deepslam")


def _pipeline_options(parser: argparse.ArgumentParser, frontends: tuple[str, ...]) -> None:
    from deepslam.backend.odometry import SCALES
    from deepslam.backend.relpose import METHODS

    parser.add_argument(
        "--frontend",
        choices=frontends,
        default="magic",
        help="magic: MagicPoint+MagicWarp; classical: Shi-Tomasi+Lucas-Kanade; oracle: true projections",
    )
    parser.add_argument(
        "--method",
        choices=METHODS,
        default="homography",
        help="relative pose: homography (dominant plane; default, most accurate on these worlds), "
        "auto (ORB-SLAM H/F selection), essential, or pycolmap",
    )
    parser.add_argument(
        "--scale",
        choices=SCALES,
        default="gt",
        help="monocular scale: gt = ground-truth step lengths; plane = known distance to the dominant plane",
    )
    parser.add_argument(
        "--plane-distance",
        type=float,
        default=None,
        help="first camera's distance to the dominant plane for --scale plane (simulation: known)",
    )
    parser.add_argument(
        "--keyframe-parallax",
        type=float,
        default=10.0,
        help="median track motion (px) since the keyframe that makes a new keyframe",
    )
    parser.add_argument("--warp-iterations", type=int, default=1, help="MagicWarp iterations (magic front-end)")
    parser.add_argument(
        "--detector-scale",
        type=int,
        choices=(1, 2),
        default=2,
        help="MagicPoint detects on the image enlarged this many times (magic front-end). 2 (default) "
        "tracks photographed textures far more accurately; 1 is faster and does better under "
        "heavy noise (README: drift table)",
    )
    parser.add_argument(
        "--no-refine",
        action="store_true",
        help="use MagicWarp's homography as it is; by default it is refined by snapping and a robust "
        "fit, and the no-motion and constant-motion guesses, refined the same way, replace it "
        "when more detections agree with them",
    )
    parser.add_argument(
        "--no-carry",
        action="store_true",
        help="report only detected points; by default (with --method homography) a track the "
        "detector misses is still reported where MagicWarp's homography carries it, for up to 20 "
        "frames; the other methods get detections only, as carried points follow the dominant plane",
    )
    parser.add_argument("--ransac", action="store_true", help="fundamental-matrix RANSAC on MagicWarp matches")
    parser.add_argument(
        "--oracle-noise",
        type=float,
        default=0.5,
        metavar="PX",
        help="standard deviation (px) of the Gaussian noise on the oracle's true projections",
    )


def _share(text: str) -> float:
    """An argparse type: a number in [0, 1]."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not 0 <= value <= 1:
        raise argparse.ArgumentTypeError(f"must be a number in [0, 1], got {text!r}")
    return value


def _common_training_options(parser: argparse.ArgumentParser, iterations: int, batch: int, lr: float) -> None:
    parser.add_argument("--iterations", type=int, default=iterations, help="total optimisation steps")
    parser.add_argument("--batch", type=int, default=batch, help="examples per step")
    parser.add_argument("--lr", type=float, default=lr, help="Adam learning rate")
    parser.add_argument("--seed", type=int, default=0, help="seed of the data stream and initialisation")
    parser.add_argument("--validate-every", type=int, default=500, help="steps between validations/checkpoints")
    parser.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    parser.add_argument(
        "--ema",
        type=float,
        default=0.0,
        metavar="DECAY",
        help="keep a moving average of the weights with this per-step decay (e.g. 0.999); it is "
        "what validation scores and best.pt / export ship (default 0: off)",
    )
    parser.add_argument(
        "--init",
        default="",
        metavar="WEIGHTS",
        help="start a new run (no last.pt in --out) from these weights: a checkpoint or shipped file; "
        "weights of a narrower network (same layers, fewer units) are embedded into the wider one "
        "so that it starts from the same function",
    )


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="deepslam", description=__doc__)
    commands = parser.add_subparsers(dest="command", required=True)

    train = commands.add_parser("train", help="train a network (resumes from its last checkpoint)")
    nets = train.add_subparsers(dest="network", required=True)
    warp = nets.add_parser("magicwarp", help="train MagicWarp on rendered point-cloud pairs")
    warp.add_argument(
        "--out", type=Path, default=Path("runs/magicwarp"), help="checkpoint folder (resumes from last.pt)"
    )
    _common_training_options(warp, iterations=40000, batch=64, lr=3e-4)
    warp.add_argument("--motion-start", type=float, default=0.3, help="motion scale of the curriculum at step 0")
    warp.add_argument("--motion-ramp", type=int, default=12000, help="steps over which motion grows to --motion-max")
    warp.add_argument("--motion-max", type=float, default=1.0, help="largest motion scale of the curriculum")
    warp.add_argument(
        "--geometry-weights",
        type=float,
        nargs=5,
        default=(0.2, 0.075, 0.075, 0.15, 0.5),
        metavar=("PLANE", "SPHERE", "CUBE", "MIXED", "HOMOGRAPHY"),
        help="how often each kind of pair is drawn: point clouds seen by two cameras (plane, sphere, "
        "cube, mixed scene) or image points moved by a random 2D homography",
    )
    warp.add_argument(
        "--widths",
        type=int,
        nargs="+",
        default=None,
        help="encoder widths, --blocks VGG blocks per 2x2 max-pool (default: the shipped network's, "
        "64 64 128 128 128 128; a new run only, a resumed run keeps its own)",
    )
    warp.add_argument(
        "--blocks",
        type=int,
        default=None,
        help="VGG blocks per stage of the encoder (default: the shipped network's, 2). With --init, "
        "weights of fewer blocks per stage are deepened: the new blocks start as identities",
    )
    warp.add_argument(
        "--hidden",
        type=int,
        default=None,
        help="width of the hidden fully connected layer (default: the shipped network's, 512; "
        "a new run only, a resumed run keeps its own)",
    )
    warp.add_argument(
        "--homography",
        type=float,
        nargs=4,
        default=(0.3, math.pi / 4, 0.35, 0.1),
        metavar=("TRANSLATION", "ROTATION", "ZOOM", "JITTER"),
        help="ranges of the 2D homography pairs at full motion: translation and corner jitter as shares "
        "of the image size, rotation in radians, zoom as +- a share",
    )
    warp.add_argument(
        "--loss-weighting",
        choices=("matches", "pairs"),
        default="matches",
        help="how the pairs of a batch weigh in the loss: matches (the paper's sum over true matches: "
        "a dense pair weighs more) or pairs (each pair's mean error, so a sparse pair weighs as "
        "much as a dense one, as in the breakdown evaluation)",
    )
    warp.add_argument(
        "--cauchy",
        type=float,
        default=0.0,
        metavar="SCALE",
        help="replace each match's squared distance in the loss by the Cauchy loss of this scale, in "
        "normalised coordinates (0.05: about 4 px across a 160 px width): alike for small errors, "
        "logarithmic for large ones (default 0: the paper's squared distance)",
    )
    warp.add_argument(
        "--max-extra",
        type=_share,
        default=0.5,
        metavar="SHARE",
        help="each image of a pair gets a random share, up to this one, of its point count in spurious "
        "random points (default 0.5; the breakdown evaluation adds 0, 20 or 40%% to image B)",
    )
    warp.add_argument(
        "--clean-a-share",
        type=_share,
        default=0.0,
        metavar="SHARE",
        help="this share of the pairs is drawn as the breakdown evaluation draws them: image A keeps "
        "every point (no dropout, no spurious points), image B every point still in view plus "
        "spurious ones, up to --max-extra of A's point count (default 0: dropout and spurious "
        "points in both images)",
    )
    warp.set_defaults(func=_train_magicwarp)
    point = nets.add_parser("magicpoint", help="train MagicPoint on Synthetic Shapes")
    point.add_argument("--variant", choices=("S", "L"), default="S", help="network size")
    point.add_argument("--out", type=Path, default=None, help="checkpoint folder (default runs/magicpoint_VARIANT)")
    _common_training_options(point, iterations=8000, batch=32, lr=1e-3)
    point.add_argument(
        "--clean-share",
        type=_share,
        default=0.0,
        help="share (0-1) of training images left without photometric noise (default 0: all noisy)",
    )
    point.add_argument(
        "--validation-per-category",
        type=int,
        default=20,
        help="validation images per Synthetic Shapes category (each scored clean and noisy)",
    )
    point.set_defaults(func=_train_magicpoint)
    export = nets.add_parser("export", help="strip a training checkpoint down to the weights that ship")
    export.add_argument("checkpoint", type=Path, help="a training checkpoint, e.g. runs/magicpoint_S/best.pt")
    export.add_argument("out", type=Path, help="where to write the weights, e.g. frontend/weights/magicpoint_S.pt")
    export.set_defaults(func=_export)

    run = commands.add_parser("run", help="run a simulated trajectory end to end, log it to MCAP, print drift")
    run.add_argument("--world", choices=("plane", "room"), default="plane", help="simulated world")
    run.add_argument(
        "--trajectory", choices=("circle", "figure8", "line", "random"), default="circle", help="camera path"
    )
    run.add_argument("--frames", type=int, default=60, help="number of frames")
    run.add_argument("--speed", type=float, default=0.5, help="camera speed (m/s)")
    run.add_argument("--fps", type=float, default=10.0, help="frame rate (frames per second)")
    run.add_argument(
        "--noise", type=float, default=0.0, help="photometric noise magnitude s (0 clean, 1 full, 2 random)"
    )
    run.add_argument(
        "--lighting", type=float, default=0.0, help="amplitude of a slow global brightness change (0.3 = 30%%)"
    )
    run.add_argument(
        "--size", type=int, nargs=2, default=(120, 160), metavar=("H", "W"), help="image size, multiples of 8"
    )
    run.add_argument(
        "--seed",
        type=int,
        default=0,
        help="seed of the world, the image noise and the random trajectory (circle, figure8 and line are fixed paths)",
    )
    run.add_argument("--out", type=Path, default=Path("out/run.mcap"), help="MCAP log to write")
    _pipeline_options(run, ("magic", "classical", "oracle"))
    run.set_defaults(func=_run)

    replay = commands.add_parser("replay", help="feed a logged run through the pipeline again, into a new log")
    replay.add_argument("log", type=Path, help="MCAP log written by `deepslam run`")
    replay.add_argument("--out", type=Path, default=Path("out/replay.mcap"), help="MCAP log to write")
    _pipeline_options(replay, ("magic", "classical"))
    replay.set_defaults(func=_replay)

    drift = commands.add_parser("drift", help="ATE/RPE/final drift of logs, side by side, with plots")
    drift.add_argument("logs", type=Path, nargs="+", help="MCAP logs holding /groundtruth/pose and /estimate/pose")
    drift.add_argument("--delta", type=int, default=1, help="frame delta of the RPE")
    drift.add_argument("--out", type=Path, default=Path("out/drift"), help="folder for the PNG plots (and TUM files)")
    drift.add_argument("--tum", action="store_true", help="also export both trajectories in TUM format")
    drift.set_defaults(func=_drift)

    evaluate = commands.add_parser("eval", help="evaluation experiments of the paper")
    evals = evaluate.add_subparsers(dest="experiment", required=True)
    detector = evals.add_parser("detector", help="Synthetic Shapes mAP/MLE table, per category, noise sweeps")
    detector.add_argument("--per-category", type=int, default=1000, help="images per category (the paper: 1000)")
    detector.add_argument(
        "--sweep-per-category",
        type=int,
        default=50,
        help="images per category for the noise-magnitude and noise-type sweeps",
    )
    detector.add_argument("--seed", type=int, default=0, help="seed of the evaluation set and its noise")
    detector.add_argument("--out", type=Path, default=Path("out/eval"), help="folder for the JSON and PNG plots")
    detector.add_argument(
        "--detectors",
        nargs="+",
        default=None,
        metavar="NAME",
        help="evaluate only these (MagicPointS, MagicPointL, MagicPointS-x4 = S with four grid shifts, "
        "MagicPointS-2x = S on the image enlarged 2x with two grid shifts, as the magic tracker "
        "runs it, FAST, Harris, Shi); default all",
    )
    detector.set_defaults(func=_eval_detector)
    warp_eval = evals.add_parser(
        "warp",
        help="MagicWarp 90%% breakdown-point table (nearest neighbour, RANSAC, MagicWarp raw, "
        "applied twice, refined, and given image B without its spurious points) and "
        "repeatability plots",
    )
    warp_eval.add_argument("--runs", type=int, default=50, help="random point sets per cell (the paper: 50)")
    warp_eval.add_argument("--seed", type=int, default=0, help="seed of the point sets")
    warp_eval.add_argument("--out", type=Path, default=Path("out/eval"), help="folder for the JSON and PNG plot")
    warp_eval.add_argument(
        "--weights",
        type=Path,
        default=None,
        help="MagicWarp weights or a training checkpoint (default: the shipped weights)",
    )
    warp_eval.set_defaults(func=_eval_warp)
    real = evals.add_parser("realimages", help="repeatability on real photographs under changing light (static camera)")
    real.add_argument("--frames", type=int, default=20, help="frames per photograph sequence")
    real.add_argument("--seed", type=int, default=0, help="seed of the lighting and noise")
    real.add_argument("--out", type=Path, default=Path("out/eval"), help="folder for the JSON")
    real.add_argument(
        "--jitter",
        type=float,
        default=0.0,
        help="also move the camera: translate every frame by up to this many pixels (0: static, "
        "as the paper's Static Corners; the JSON is then named realimages_jitterPX)",
    )
    real.set_defaults(func=_eval_realimages)
    matrix = evals.add_parser("pipeline", help="drift over worlds x front-ends x noise (averaged over seeds)")
    matrix.add_argument(
        "--worlds",
        nargs="+",
        choices=("plane", "room"),
        default=["plane", "room"],
        help="simulated worlds: plane (one textured wall) and/or room (walls, floor, boxes)",
    )
    matrix.add_argument(
        "--frontends",
        nargs="+",
        choices=("oracle", "magic", "classical"),
        default=["oracle", "magic", "classical"],
        help="front-ends to compare (oracle: true projections with 0.5 px noise, the reference)",
    )
    matrix.add_argument(
        "--noise",
        nargs="+",
        type=float,
        default=[0.0, 1.0],
        help="photometric noise magnitudes s to run each at (0 clean, 1 full, as `deepslam run --noise`)",
    )
    matrix.add_argument("--frames", type=int, default=60, help="frames per run")
    matrix.add_argument(
        "--seeds", type=int, default=6, help="runs per cell (seeds 0..N-1; the worlds differ by seed: textures, layout)"
    )
    matrix.add_argument(
        "--scale",
        choices=("gt", "plane"),
        default="gt",
        help="monocular scale: gt = ground-truth step lengths; plane = known distance to the dominant plane",
    )
    matrix.add_argument(
        "--detector-scale",
        type=int,
        choices=(1, 2),
        default=2,
        help="MagicPoint detects on the image enlarged this many times (magic front-end, as in `deepslam run`)",
    )
    matrix.add_argument(
        "--trajectory", choices=("circle", "figure8", "line", "random"), default="circle", help="camera path"
    )
    matrix.add_argument(
        "--out",
        type=Path,
        default=Path("out/eval"),
        help="folder for pipeline.json (the table, with per-seed ATE, is printed too)",
    )
    matrix.set_defaults(func=_eval_pipeline)

    bench = commands.add_parser("bench", help="timings on one CPU thread, beside the paper's")
    targets = bench.add_subparsers(dest="target", required=True)
    for target, text in (
        ("detector", "MagicPoint S/L forward pass (BatchNorm folded) and point extraction"),
        ("warp", "MagicWarp forward pass (BatchNorm folded)"),
        ("pipeline", "per-frame time of every pipeline stage (magic front-end, no rendering)"),
    ):
        sub = targets.add_parser(target, help=text)
        if target == "pipeline":
            sub.add_argument("--frames", type=int, default=60, help="frames of the simulated run, each timed once")
            sub.add_argument(
                "--detector-scale",
                type=int,
                choices=(1, 2),
                default=2,
                help="MagicPoint detects on the image enlarged this many times (as in `deepslam run`)",
            )
        else:
            sub.add_argument("--repeats", type=int, default=100, help="timed repetitions (median reported)")
        sub.set_defaults(func=_bench)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    import torch

    torch.set_num_threads(getattr(args, "threads", 1))  # small networks: one thread is fastest, and the paper's set-up
    try:
        args.func(args)
    except (ValueError, FileNotFoundError, RuntimeError) as error:
        print(f"deepslam: error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("deepslam: interrupted", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
