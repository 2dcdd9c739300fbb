"""How precisely a MagicPoint's points and its homographic-adaptation labels follow a sub-pixel motion, for
each sub-pixel refinement of their peaks: on random 160x120 views of the validation photographs (never
trained on, never used by an evaluation), each view against itself moved by a random shift of up to 2 px
along x and y (bilinear, reflected borders), the mean and median distance between repeated points (a point
with one of the other view within 2 px once moved, both ways: ``metrics.repeated``, as `deepslam eval
realimages` measures localisation).

    python examples/subpixel_precision.py --photos WALLPAPERS GNOME
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from deepslam.frontend.evaluation.detector import moved
from deepslam.frontend.evaluation.metrics import repeated
from deepslam.frontend.magicpoint import MagicPoint
from deepslam.frontend.points import SUBPIXEL
from deepslam.frontend.training.adaptation import AdaptConfig, label_views
from deepslam.sim import photos

VIEW_SIZE = (120, 160)  # rows, columns


def view_pairs(
    validation: list[photos.Photo], count: int, seed: int, whole_pixels: bool = False
) -> list[tuple[np.ndarray, np.ndarray]]:
    """``count`` random views of the photographs, each with itself moved: [(views (2, *VIEW_SIZE) uint8, the
    homography (3, 3) from the first to the second: a shift, rounded to whole pixels if ``whole_pixels``)],
    drawn with ``seed``."""
    rng = np.random.default_rng(seed)
    pairs = []
    for index in range(count):
        view = photos.random_view(validation[index % len(validation)].load(), rng, VIEW_SIZE)
        shift = rng.uniform(-2.0, 2.0, 2)
        shift = np.round(shift) if whole_pixels else shift
        move = np.array([[1.0, 0.0, shift[0]], [0.0, 1.0, shift[1]], [0.0, 0.0, 1.0]])
        pairs.append((np.stack([view, moved(view, move)]), move))
    return pairs


def summary(distances: list[np.ndarray]) -> str:
    """Mean / median of the distances (px) of every pair, and how many."""
    joined = np.concatenate(distances)
    return f"{joined.mean():.3f} / {np.median(joined):.3f} ({len(joined)})"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--photos",
        nargs="*",
        default=[],
        metavar="DIR",
        help="folders of photographs, as `deepslam train magicpoint-ha --photos` takes them",
    )
    parser.add_argument(
        "--weights",
        type=Path,
        default=None,
        help="MagicPoint S-HA weights or checkpoint that detects and labels (default: shipped)",
    )
    parser.add_argument("--views", type=int, default=24, help="views of the validation photographs")
    parser.add_argument("--seed", type=int, default=7, help="seed of the views, shifts and warps")
    parser.add_argument(
        "--whole-pixels", action="store_true", help="shifts rounded to whole pixels (no interpolation, grid phase only)"
    )
    args = parser.parse_args()
    if args.views < 1:
        parser.error(f"--views must be at least 1, got {args.views}")
    try:
        validation = photos.split(tuple(args.photos))["validation"]
        net = MagicPoint.pretrained("S-HA", path=args.weights).net
    except (FileNotFoundError, ValueError) as error:
        parser.error(str(error))
    pairs = view_pairs(validation, args.views, args.seed, args.whole_pixels)
    print(f"{len(pairs)} views of {len(validation)} validation photographs; distance px mean / median (points)")
    print("refine    labels (64 warps)        detector (one pass)")
    for refine in SUBPIXEL:
        detector, config = MagicPoint(net, subpixel=refine), AdaptConfig(label_refine=refine)
        labelled, detected = [], []
        for index, (views, move) in enumerate(pairs):
            labels = label_views(net, views, np.random.default_rng([args.seed, index]), config)
            labelled.append(repeated(*(rows[~np.isnan(rows[:, 0])] for rows in labels), move, VIEW_SIZE)[1])
            detected.append(repeated(*(detector.detect(view) for view in views), move, VIEW_SIZE)[1])
        print(f"{refine:8s}  {summary(labelled):23s}  {summary(detected)}")


if __name__ == "__main__":
    main()
