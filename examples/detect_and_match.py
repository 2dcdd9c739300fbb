"""Detect corners in two views of a Synthetic Shapes image and match them without descriptors.

python examples/detect_and_match.py
"""

import numpy as np

from deepslam.frontend import MagicPoint, MagicWarp, match
from deepslam.sim import shapes
from deepslam.sim.homography import HomographyConfig, sample_homography, warp_image_and_points

rng = np.random.default_rng(0)
image_a, _ = shapes.render("checkerboards", rng)
H_true = sample_homography(
    rng, image_a.shape, HomographyConfig(translation=0.03, rotation=0.05, scale=0.05, perspective=0.01)
)
image_b, _ = warp_image_and_points(image_a, np.zeros((0, 2)), H_true)

detector, warp = MagicPoint.pretrained("S"), MagicWarp.pretrained()
points_a, points_b = detector.detect(image_a), detector.detect(image_b)
H = warp.estimate(points_a, points_b, image_a.shape, iterations=2)
pairs = match(points_a, points_b, H, max_dist=3.0)
print(f"{len(points_a)} and {len(points_b)} corners, {len(pairs)} matches")
print("estimated H_ab:\n", np.round(H, 3), "\ntrue H_ab:\n", np.round(H_true, 3))
