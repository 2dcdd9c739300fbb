"""A pose graph in a dozen lines: prior, between factors, ISAM2, covariance, batch cross-check.

python examples/pose_graph.py
"""

import numpy as np

from deepslam.backend.config import GraphConfig
from deepslam.backend.graph import PoseGraph
from deepslam.sim.camera import pose

step = pose(np.array([0.0, 0.1, 0.0]), np.array([0.5, 0.0, 0.0]))  # move 0.5 m, turn 0.1 rad
sigmas = np.array([0.01] * 3 + [0.05] * 3)  # rotation first, then translation
graph = PoseGraph(np.eye(4), GraphConfig(window=None))  # keep every pose, for the batch cross-check
for k in range(1, 10):
    graph.add_pose(k, graph.pose(k - 1) @ step)
    graph.add_between(k - 1, k, step, sigmas)
    graph.update()
print("last pose:\n", graph.pose(9).round(3))
print("its marginal covariance diagonal:", np.diag(graph.covariance(9)).round(5))
print("ISAM2 vs batch LM, max difference:", np.abs(graph.poses() - graph.batch_solve()).max())
