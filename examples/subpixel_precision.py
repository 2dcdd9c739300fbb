"""How precisely a MagicPoint's points and its homographic-adaptation labels follow a sub-pixel motion, for
each sub-pixel refinement of their peaks: on random 160x120 views of the validation photographs (never
trained on, never used by an evaluation), each view against itself moved by a random shift of up to 2 px
along x and y (bilinear), the mean and median distance between a point of the view, moved, and the nearest
point of the moved view, over the points that have one within 2 px.

    python examples/subpixel_precision.py --photos WALLPAPERS GNOME
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from deepslam.frontend.magicpoint import MagicPoint
from deepslam.frontend.points import SUBPIXEL
from deepslam.frontend.training.adaptation import AdaptConfig, label_views
from deepslam.sim import photos
from deepslam.sim.homography import warp_image

VIEW_SIZE = (120, 160)  # rows, columns
MATCH_PX = 2.0
BORDER_PX = 8  # points this close to the edge may leave the moved view


def shifted_views(
    validation: list[photos.Photo], count: int, seed: int, whole_pixels: bool = False
) -> list[tuple[np.ndarray, np.ndarray]]:
    """``count`` random views of the photographs, each with itself moved: [(views (2, *VIEW_SIZE) uint8, the
    shift (2,) px from the first to the second, rounded to whole pixels if ``whole_pixels``)], drawn with
    ``seed``."""
    rng = np.random.default_rng(seed)
    pairs = []
    for index in range(count):
        view = photos.random_view(validation[index % len(validation)].load(), rng, VIEW_SIZE)
        shift = rng.uniform(-2.0, 2.0, 2)
        shift = np.round(shift) if whole_pixels else shift
        moved = warp_image(view, np.array([[1.0, 0.0, shift[0]], [0.0, 1.0, shift[1]], [0.0, 0.0, 1.0]]))
        pairs.append((np.stack([view, moved]), shift))
    return pairs


def followed_distances(points: np.ndarray, points_moved: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """Distances (M,) px from each point (N, 2+) away from the border, moved by ``shift``, to the nearest of
    ``points_moved`` (K, 2+), for the M points whose nearest lies within ``MATCH_PX``."""
    last = np.array(VIEW_SIZE[::-1]) - 1  # the last pixel's (x, y)
    inside = np.all((points[:, :2] >= BORDER_PX) & (points[:, :2] <= last - BORDER_PX), axis=1)
    expected = points[inside, :2] + shift
    if not len(expected) or not len(points_moved):
        return np.zeros(0)
    nearest = np.linalg.norm(expected[:, None] - points_moved[None, :, :2], axis=2).min(1)
    return nearest[nearest < MATCH_PX]


def summary(distances: list[np.ndarray]) -> str:
    joined = np.concatenate(distances)
    return f"{joined.mean():.3f} / {np.median(joined):.3f} ({len(joined)})"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
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
    pairs = shifted_views(validation, args.views, args.seed, args.whole_pixels)
    print(f"{len(pairs)} views of {len(validation)} validation photographs; distance px mean / median (points)")
    print("refine    labels (64 warps)        detector (one pass)")
    for refine in SUBPIXEL:
        detector, config = MagicPoint(net, subpixel=refine), AdaptConfig(label_refine=refine)
        labelled, detected = [], []
        for index, (views, shift) in enumerate(pairs):
            labels = label_views(net, views, np.random.default_rng([args.seed, index]), config)
            labelled.append(followed_distances(*(rows[~np.isnan(rows[:, 0])] for rows in labels), shift))
            detected.append(followed_distances(*(detector.detect(view) for view in views), shift))
        print(f"{refine:8s}  {summary(labelled):23s}  {summary(detected)}")


if __name__ == "__main__":
    main()
