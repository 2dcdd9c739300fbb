#!/usr/bin/env bash
# Regenerates every figure in docs/ from the shipped weights (about two hours with JOBS=2 on two cores; not part
# of CI). Each command writes its .txt, .json and plots into its --out folder.
set -euo pipefail
cd "$(dirname "$0")/.."
JOBS=${JOBS:-2}
TIME="/usr/bin/time -f %e -o"  # wall seconds of a command, into a file
deepslam eval realimages --out docs/eval --jobs "$JOBS"
deepslam eval realimages --out docs/eval --jobs "$JOBS" --jitter 2
python examples/shift_repeatability.py --detectors MagicPointS MagicPointS-HA MagicPointS-2x Harris \
  > docs/eval/shift_repeatability.txt
# these two need the training photographs (README, "Training and beyond one machine"): PHOTOS="DIR DIR"
if [ -n "${PHOTOS:-}" ]; then
  python examples/subpixel_precision.py --photos $PHOTOS > docs/eval/subpixel_precision.txt
  python examples/subpixel_precision.py --photos $PHOTOS --whole-pixels > docs/eval/subpixel_precision_whole.txt
fi
deepslam eval detector --out docs/eval --jobs "$JOBS" \
  --detectors MagicPointS MagicPointS-HA MagicPointS-2x FAST Harris Shi
deepslam eval detector --out docs/eval/detector_L --jobs "$JOBS" --per-category 300 --sweep-per-category 10 \
  --detectors MagicPointL
deepslam eval warp --out docs/eval --jobs "$JOBS"
# the pipeline sweep of the plane and the room on the circle without lighting changes (--scale gt)
deepslam eval pipeline --out docs/eval --jobs "$JOBS" --worlds plane room --trajectories circle --lighting 0
deepslam eval pipeline --out docs/eval/pipeline_lighting --jobs "$JOBS" --worlds plane room --trajectories circle \
  --lighting 0.3
deepslam eval pipeline --out docs/eval/pipeline_paths --jobs "$JOBS" --worlds plane room \
  --trajectories figure8 line random --lighting 0
deepslam eval pipeline --out docs/eval/pipeline_paths_lighting --jobs "$JOBS" --worlds plane room \
  --trajectories figure8 line random --lighting 0.3
deepslam eval pipeline --out docs/eval/pipeline_S --jobs "$JOBS" --worlds plane room --trajectories circle --lighting 0 \
  --frontends magic --detector S
deepslam eval pipeline --out docs/eval/pipeline_scale1 --jobs "$JOBS" --worlds plane room --trajectories circle \
  --lighting 0 --frontends magic --detector-scale 1
# the local map (--scale map) in all three worlds, beside the same runs with true step lengths, 3 seeds
MAP="--worlds plane room clutter --trajectories circle forward --noise 0 0.5 --lighting 0 --seeds 3"
deepslam eval pipeline --out docs/eval/pipeline_map --jobs "$JOBS" $MAP --scale map
deepslam eval pipeline --out docs/eval/pipeline_map_gt --jobs "$JOBS" $MAP --scale gt
deepslam eval pipeline --out docs/eval/pipeline_map_paths --jobs "$JOBS" --worlds plane room \
  --trajectories figure8 line random --noise 0 0.5 --lighting 0 --seeds 3 --scale map
# tracks followed by Lucas-Kanade (--follow): drift, and how often tracks stay on their points
deepslam eval pipeline --out docs/eval/pipeline_map_follow --jobs "$JOBS" --worlds room clutter \
  --trajectories circle forward --noise 0 0.5 --lighting 0 --seeds 3 --frontends magic --follow --scale map
python examples/track_consistency.py > docs/eval/track_consistency.txt
# each run's ATE over its limit, over the whole run and from the map's first frame on, and over the causal limit
for F in oracle classical magic; do python examples/limit_split.py --frontend $F > docs/eval/limit_split_$F.txt; done
# how precisely the map locates the oracle's frames, beside PnP on the true points of their observations
python examples/located_precision.py > docs/eval/located_precision.txt
# how well two views measure the frames before a map, by how far their tracks moved
for F in oracle classical magic; do python examples/first_frames.py --frontend $F > docs/eval/first_frames_$F.txt; done
# the map's bundle adjustment (gtsam) beside pycolmap's on the same windows
python examples/bundle_adjusters.py > docs/eval/bundle_adjusters.txt
# timings, one process at a time
deepslam bench detector --out docs/eval
deepslam bench warp --out docs/eval
deepslam bench pipeline --out docs/eval
deepslam bench pipeline --out docs/eval/bench_S --detector S
deepslam bench pipeline --out docs/eval/bench_long --frames 5000 --rounds 1
# speed-ups on this machine: a sweep in one process and in two, and MagicPoint S training on one rank and two
SWEEP="deepslam eval pipeline --trajectories circle --lighting 0 --noise 0 --worlds plane --seeds 6 -q"
$TIME docs/eval/seconds_sweep_jobs1.txt $SWEEP --out out/speedup1
$TIME docs/eval/seconds_sweep_jobs2.txt $SWEEP --out out/speedup2 --jobs 2
TRAIN="train magicpoint --iterations 60 --batch 32 --validate-every 60 --validation-per-category 1 -q"
$TIME docs/eval/seconds_train_ranks1.txt deepslam $TRAIN --out out/ranks1
$TIME docs/eval/seconds_train_ranks2.txt python -m torch.distributed.run --standalone --nproc_per_node 2 \
  -m deepslam $TRAIN --out out/ranks2
# the default run beside the oracle and the classical front-end, its drift plot and report
deepslam run --out out/run.mcap | tee docs/eval/run_default.txt
deepslam run --frontend oracle --out out/oracle.mcap
deepslam run --frontend classical --out out/classical.mcap
rm -f docs/drift.txt docs/drift.json  # drift keeps an earlier drift's results: these are the last run's
deepslam drift out/run.mcap out/oracle.mcap out/classical.mcap --out docs | tee docs/eval/drift_default.txt
deepslam report out/run.mcap out/oracle.mcap out/classical.mcap --out out/report.html
