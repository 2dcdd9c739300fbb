"""The pipeline on a folder of images of your own: no ground truth, no simulator. Frames are taken in the
order of their file names, ``--fps`` apart; the camera is a pinhole of ``--fov`` degrees across the width
(give your calibration's fx, fy, cx, cy with ``--K`` instead). Prints each frame's position (up to scale)
and how many points it tracked.

    python examples/own_frames.py FOLDER [--fps 30] [--fov 70 | --K FX FY CX CY] [--frontend magic]
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import cv2
import numpy as np

from deepslam import InputError, Pipeline, PipelineConfig, TrackerConfig


def camera(size: tuple[int, int], fov_deg: float, K: list[float] | None) -> np.ndarray:
    """K (3, 3) from fx, fy, cx, cy, or a pinhole of ``fov_deg`` across the width of an image of ``size`` (H, W)."""
    if K is not None:
        fx, fy, cx, cy = K
    else:
        fx = fy = size[1] / 2 / math.tan(math.radians(fov_deg) / 2)
        cx, cy = (size[1] - 1) / 2, (size[0] - 1) / 2
    return np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folder", type=Path, help="images (PNG or JPEG), in the order of their names")
    parser.add_argument("--fps", type=float, default=30.0, help="frames per second (stamps)")
    parser.add_argument("--fov", type=float, default=70.0, help="horizontal field of view in degrees")
    parser.add_argument("--K", type=float, nargs=4, metavar=("FX", "FY", "CX", "CY"), help="the camera matrix")
    parser.add_argument("--frontend", default="magic", choices=("magic", "classical"), help="the front-end")
    args = parser.parse_args()
    if not (args.fps > 0 and 0 < args.fov < 180):
        parser.error(f"--fps must be positive and --fov between 0 and 180 degrees, got {args.fps} and {args.fov}")
    if not args.folder.is_dir():
        parser.error(f"{args.folder}: no such folder")
    files = sorted(p for p in args.folder.iterdir() if p.suffix.lower() in (".png", ".jpg", ".jpeg"))
    if not files:
        parser.error(f"{args.folder}: no PNG or JPEG images")
    pipeline = Pipeline(PipelineConfig(TrackerConfig(args.frontend)))
    for index, path in enumerate(files):
        image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)  # uint8 (H, W), None where it does not decode
        if image is None:
            parser.exit(1, f"own_frames.py: {path}: not a readable image\n")
        try:
            result = pipeline.process(image, camera(image.shape, args.fov, args.K), round(index * 1e9 / args.fps))
        except InputError as error:  # a frame of another size, a K that does not fit the image, ...
            parser.exit(1, f"own_frames.py: {path}: {error}\n")
        x, y, z = result.T_world_cam[:3, 3]
        print(f"{index:4d}  {x:8.3f} {y:8.3f} {z:8.3f}  tracks {len(result.tracks.ids):3d}  lost {result.lost}")
    trajectory = pipeline.trajectory()
    length = np.linalg.norm(np.diff(trajectory[:, :3, 3], axis=0), axis=1).sum()
    print(f"{len(trajectory)} frames, path length {length:.3f} (in units of the map's first baseline)")


if __name__ == "__main__":
    main()
