"""The README's Python example: detect corners in two views and match them without descriptors.

python examples/quickstart.py
"""

import numpy as np

from deepslam.frontend import MagicPoint, MagicWarp, match
from deepslam.sim import shapes
from deepslam.sim.homography import HomographyConfig, sample_homography, warp_image_and_points

rng = np.random.default_rng(0)
image_a, _ = shapes.render("checkerboards", rng)  # uint8 120x160
H_true = sample_homography(rng, image_a.shape, HomographyConfig(0.03, 0.05, 0.05, 0.01))
image_b, _ = warp_image_and_points(image_a, np.zeros((0, 2)), H_true)
detector, warp = MagicPoint.pretrained("S-HA"), MagicWarp.pretrained()
points_a, points_b = detector.detect(image_a), detector.detect(image_b)  # (N, 3): x, y, score
H_ab = warp.estimate(points_a, points_b, image_a.shape)  # 3x3, H[2, 2] == 1
pairs = match(points_a, points_b, H_ab, max_dist=3.0)  # (K, 2) indices into a and b
print(f"{len(pairs)} matches; H_ab =\n{H_ab.round(3)}")
