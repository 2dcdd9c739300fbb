"""Run the odometry on a simulated room with the classical front-end, log it, and read the log back.

python examples/simulated_run.py
"""

from deepslam.backend.config import OdometryConfig
from deepslam.backend.evaluation.runs import simulate
from deepslam.frontend.config import TrackerConfig
from deepslam.logs.reader import read_frames
from deepslam.sim.scenario import ScenarioConfig

result = simulate(
    ScenarioConfig(world="room", trajectory="figure8", frames=40),
    TrackerConfig(frontend="classical"),
    OdometryConfig(scale="gt"),
    out="out/example.mcap",
)
print({k: round(v, 4) for k, v in result["summary"].items()})
for frame in list(read_frames("out/example.mcap"))[:3]:
    print(frame.stamp_ns, len(frame.tracks), frame.T_estimate[:3, 3].round(3))
