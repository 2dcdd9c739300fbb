"""`deepslam`: one entry point wiring the packages; every command's logic lives in them."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path


def _train_magicwarp(args: argparse.Namespace) -> None:
    from frontend.train_magicwarp import TrainConfig, run
    run(args.out, TrainConfig(iterations=args.iterations, batch=args.batch, lr=args.lr, seed=args.seed,
                              motion_ramp=args.motion_ramp, validate_every=args.validate_every,
                              threads=args.threads))


def _train_magicpoint(args: argparse.Namespace) -> None:
    from frontend.train_magicpoint import TrainConfig, run
    run(args.out or Path(f"runs/magicpoint_{args.variant}"),
        TrainConfig(variant=args.variant, iterations=args.iterations, batch=args.batch, lr=args.lr, seed=args.seed,
                    validate_every=args.validate_every, threads=args.threads))


def _eval_detector(args: argparse.Namespace) -> None:
    import json

    from frontend import evaluate_detector as ev
    if args.per_category < 1 or args.sweep_per_category < 1:
        raise ValueError("--per-category and --sweep-per-category must be at least 1")
    args.out.mkdir(parents=True, exist_ok=True)
    result = ev.report(ev.available_detectors(), args.per_category, args.sweep_per_category, args.seed)
    print("\n".join(ev.table_lines(result) + [""] + ev.category_lines(result)))
    (args.out / "detector.json").write_text(json.dumps(result, indent=1))
    for path in ev.save_plots(result, args.out) + [args.out / "detector.json"]:
        print(f"wrote {path}")


def _common_training_options(parser: argparse.ArgumentParser, iterations: int, batch: int, lr: float) -> None:
    parser.add_argument("--iterations", type=int, default=iterations, help="total optimisation steps")
    parser.add_argument("--batch", type=int, default=batch, help="examples per step")
    parser.add_argument("--lr", type=float, default=lr, help="Adam learning rate")
    parser.add_argument("--seed", type=int, default=0, help="seed of the data stream and initialisation")
    parser.add_argument("--validate-every", type=int, default=500, help="steps between validations/checkpoints")
    parser.add_argument("--threads", type=int, default=1, help="torch CPU threads")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="deepslam", description=__doc__)
    commands = parser.add_subparsers(dest="command", required=True)

    train = commands.add_parser("train", help="train a network (resumes from its last checkpoint)")
    nets = train.add_subparsers(dest="network", required=True)
    warp = nets.add_parser("magicwarp", help="train MagicWarp on rendered point-cloud pairs")
    warp.add_argument("--out", type=Path, default=Path("runs/magicwarp"), help="checkpoint folder (resumes from last.pt)")
    _common_training_options(warp, iterations=40000, batch=64, lr=3e-4)
    warp.add_argument("--motion-ramp", type=int, default=12000, help="steps over which camera motion grows to full")
    warp.set_defaults(func=_train_magicwarp)
    point = nets.add_parser("magicpoint", help="train MagicPoint on Synthetic Shapes")
    point.add_argument("--variant", choices=("S", "L"), default="S", help="network size")
    point.add_argument("--out", type=Path, default=None, help="checkpoint folder (default runs/magicpoint_VARIANT)")
    _common_training_options(point, iterations=8000, batch=32, lr=1e-3)
    point.set_defaults(func=_train_magicpoint)

    evaluate = commands.add_parser("eval", help="evaluation experiments of the paper")
    evals = evaluate.add_subparsers(dest="experiment", required=True)
    detector = evals.add_parser("detector", help="Synthetic Shapes mAP/MLE table, per category, noise sweeps")
    detector.add_argument("--per-category", type=int, default=1000, help="images per category (the paper: 1000)")
    detector.add_argument("--sweep-per-category", type=int, default=100,
                          help="images per category for the noise-magnitude and noise-type sweeps")
    detector.add_argument("--seed", type=int, default=0, help="seed of the evaluation set and its noise")
    detector.add_argument("--out", type=Path, default=Path("out/eval"), help="folder for the JSON and PNG plots")
    detector.set_defaults(func=_eval_detector)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        args.func(args)
    except (ValueError, FileNotFoundError) as error:
        print(f"deepslam: error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("deepslam: interrupted", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
