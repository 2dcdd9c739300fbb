"""How well a detector's points follow the image when it moves by a fraction of MagicPoint's 8-pixel cell:
repeatability (eps 2 px, at the N where it peaks) and the localisation error of repeated points between
each benchmark photograph (160x120) and the same photograph shifted right by d pixels (bilinear).
A detector that moves with the image scores the same at every shift; a cell grid that aliases scores
high at d = 8 and low in between.

    python examples/shift_repeatability.py --detectors MagicPointS MagicPointS-HA Harris
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from deepslam.frontend.evaluation.detector import PHOTOS, available_detectors, moved, sequence_repeatability
from deepslam.sim.world import photo


def shifted_pairs(images: list[np.ndarray], shift_px: float) -> list[tuple[list[np.ndarray], list[np.ndarray]]]:
    """Each image and itself moved right by ``shift_px`` pixels (reflected border), with the homography
    (3, 3) from the first to the second, as ``sequence_repeatability`` takes them."""
    move = np.array([[1.0, 0.0, shift_px], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    return [([image, moved(image, move)], [move]) for image in images]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--detectors", nargs="+", default=["MagicPointS", "MagicPointS-HA", "Harris"],
                        help="names as `deepslam eval realimages --detectors` takes them")  # fmt: skip
    parser.add_argument("--weights", nargs="*", default=[], type=Path,
                        help="also MagicPoint from these weights files or checkpoints (named by path)")  # fmt: skip
    parser.add_argument("--shifts", nargs="+", type=float, default=[0.5, 1, 2, 3, 4, 8], help="shifts in pixels")
    args = parser.parse_args()
    try:
        known = available_detectors(weights=tuple(args.weights))
    except (FileNotFoundError, ValueError) as error:
        parser.error(str(error))
    unknown = [name for name in args.detectors if name not in known]
    if unknown:
        parser.error(f"unknown detector {', '.join(unknown)}; expected some of {', '.join(known)}")
    names = args.detectors + [str(path) for path in args.weights]
    images = [photo(name, (120, 160)) for name in PHOTOS]
    print("repeatability (localisation error px) against the shift: " + "  ".join(f"{d:g} px" for d in args.shifts))
    for name in names:
        figures = [sequence_repeatability(known[name], shifted_pairs(images, d)) for d in args.shifts]
        print(f"{name:16s}  " + "  ".join(f"{f['repeatability']:.3f} ({f['localization_error']:.2f})" for f in figures))


if __name__ == "__main__":
    main()
