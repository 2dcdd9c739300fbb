"""The odometry's one keyframe decision and the phases it reports."""

from dataclasses import replace

import pytest

from deepslam.backend.config import OdometryConfig, PipelineConfig
from deepslam.backend.evaluation.runs import simulated_frames
from deepslam.backend.evaluation.truth import TrueFrame, run_pipeline
from deepslam.backend.keyframes import KeyframeEvidence, KeyframePolicy, MapLocation, Phase
from deepslam.frontend.config import TrackerConfig
from deepslam.frontend.tracking import Truth
from deepslam.sim.scenario import Scenario, ScenarioConfig

STEADY = KeyframeEvidence(
    lost_in_a_row=0, map_started=False, shared=100, parallax_px=2.0, against_keyframe=True, confirmed=90,
    map_waiting=False, tracks=120,
)  # fmt: skip
POLICY = KeyframePolicy(OdometryConfig())


def test_a_frame_that_tracks_its_keyframe_well_is_no_keyframe():
    decision = POLICY.decide(STEADY)
    assert not decision.keyframe and not decision.restart and decision.reason == ""


@pytest.mark.parametrize(
    "change, reason",
    [
        ({"lost_in_a_row": 3}, "lost 3 frames in a row: tracking starts again"),
        ({"map_started": True}, "a map starts"),
        ({"shared": 19}, "19 tracks shared with the keyframe"),
        ({"parallax_px": 10.5}, "tracks moved 10.5 px"),
        ({"confirmed": 12}, "12 pairs confirmed"),
    ],
)
def test_each_rule_names_itself(change, reason):
    decision = POLICY.decide(replace(STEADY, **change))
    assert decision.keyframe and decision.reason == reason
    assert decision.restart == ("lost_in_a_row" in change)


def test_the_first_rule_that_holds_wins():
    both = replace(STEADY, lost_in_a_row=5, map_started=True, shared=3)
    assert POLICY.decide(both).restart
    assert POLICY.decide(replace(both, lost_in_a_row=0)).reason == "a map starts"


def test_a_map_waiting_to_start_keeps_its_keyframe_while_the_baseline_grows():
    assert not POLICY.decide(replace(STEADY, parallax_px=30.0, map_waiting=True)).keyframe
    assert not POLICY.decide(replace(STEADY, confirmed=12, against_keyframe=False)).keyframe  # the older keyframe's


def test_a_frame_located_in_the_map_waits_for_a_baseline_that_triangulates():
    thin = replace(STEADY, location=MapLocation(located=20, first_located=60, baseline_px=3.0))
    assert not POLICY.decide(thin).keyframe  # PnP still locates 12: nothing new could be triangulated
    assert POLICY.decide(replace(thin, location=replace(thin.location, baseline_px=6.5))).reason == (
        "located 20 landmarks, the keyframe's first frame 60"
    )
    starved = replace(thin, location=replace(thin.location, located=10))
    assert POLICY.decide(starved).keyframe  # too few for PnP: no waiting
    few = replace(STEADY, tracks=400, location=MapLocation(located=50, first_located=60, baseline_px=7.0))
    assert POLICY.decide(few).reason == "located 50 landmarks of 400 tracks"
    wide = replace(STEADY, location=MapLocation(located=60, first_located=60, baseline_px=10.0))
    assert POLICY.decide(wide).reason == "a baseline of 10.0 px at the landmarks"


def blinded(frame: TrueFrame, keep: int = 5) -> TrueFrame:
    """``frame`` with the oracle seeing only ``keep`` of its landmarks (too few for a pose)."""
    return replace(frame, landmarks=Truth(frame.landmarks.ids[:keep], frame.landmarks.pixels[:keep]))


def test_the_pipeline_reports_its_phase_and_why_each_keyframe_is_one():
    scenario = Scenario(ScenarioConfig(world="clutter", trajectory="circle", frames=30, seed=1))
    frames, oracle = list(simulated_frames(scenario)), PipelineConfig(TrackerConfig("oracle"))
    frames[2] = blinded(frames[2])  # a frame lost before the map
    results = [result for _, _, result in run_pipeline(frames, oracle)]
    phases = [result.phase for result in results]
    started = phases.index(Phase.TRACKING)
    assert 1 < started < 20 and set(phases[:started]) == {Phase.INITIALISING, Phase.LOST}
    assert all((phase == Phase.LOST) == result.lost for phase, result in zip(phases, results, strict=True))
    assert set(phases[started:]) == {Phase.TRACKING}
    assert results[started].keyframe and results[started].keyframe_reason == "a map starts"
    assert all(bool(result.keyframe_reason) == result.keyframe for result in results)
    gt = PipelineConfig(TrackerConfig("oracle"), OdometryConfig(scale="gt"))
    frames = simulated_frames(Scenario(ScenarioConfig(frames=6)))
    assert [r.phase for _, _, r in run_pipeline(frames, gt)][1:] == [Phase.TRACKING] * 5  # no map to wait for
