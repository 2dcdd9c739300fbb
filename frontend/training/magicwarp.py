"""Training MagicWarp on point clouds rendered into two virtual cameras (``sim.pointclouds``), mixed
with image points moved by random 2D homographies.

A curriculum widens the camera motion from small to full as training goes: the network only starts
to learn from small motions. Validation tracks match repeatability in every cell of the breakdown
table at the paper's breakdown magnitudes (``deepslam.frontend.evaluation.warp.validation_set``), not the loss.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal, get_args

import numpy as np
import torch

from deepslam.errors import InputError
from deepslam.frontend.cells import points_to_cells_batch
from deepslam.frontend.config import MagicWarpConfig
from deepslam.frontend.magicwarp import MagicWarpNet, normalizer
from deepslam.frontend.nets import read_weights
from deepslam.frontend.training.loop import LoopConfig, train
from deepslam.sim.homography import HomographyConfig
from deepslam.sim.pointclouds import PairConfig, sample_pair

LossWeighting = Literal["matches", "pairs"]
LOSS_WEIGHTINGS: tuple[str, ...] = get_args(LossWeighting)


def warp_loss(
    H: torch.Tensor,
    true_a: torch.Tensor,
    true_b: torch.Tensor,
    mask: torch.Tensor,
    weighting: str = "matches",
    cauchy: float = 0.0,
) -> torch.Tensor:
    """||H x_a - x_b||^2 in normalised coordinates, averaged over the batch's true matches.

    H (B, 3, 3); true_a, true_b (B, M, 2); mask (B, M) bool marks real (not padding) matches.
    ``weighting`` "matches" (the paper's sum over matches) lets a pair weigh as much as it has matches;
    "pairs" averages within each pair first, so every pair weighs the same, as in the breakdown
    experiment, where a sparse pair counts as much as a dense one.
    ``cauchy`` > 0 replaces each squared distance d^2 by the Cauchy loss c^2 log(1 + d^2 / c^2) of that
    scale c (normalised units; 0.05 is about 4 px across 160): the same for small errors, only logarithmic for
    large ones, so a pair the network is unsure of pulls its estimate less toward the mean.
    """
    if weighting not in LOSS_WEIGHTINGS:
        raise InputError(f"unknown loss weighting {weighting!r}; expected one of {', '.join(LOSS_WEIGHTINGS)}")
    projected = true_a @ H[:, :2, :2].transpose(1, 2) + H[:, None, :2, 2]
    depth = true_a @ H[:, 2:, :2].transpose(1, 2) + H[:, None, 2:, 2]
    error = ((projected / depth.clamp(min=0.1) - true_b) ** 2).sum(-1)
    if cauchy > 0:
        error = cauchy**2 * torch.log1p(error / cauchy**2)
    error = error * mask
    if weighting == "matches":
        return error.sum() / mask.sum().clamp(min=1)
    counts = mask.sum(1)
    return (error.sum(1) / counts.clamp(min=1)).sum() / (counts > 0).sum().clamp(min=1)


@dataclass(frozen=True)
class TrainConfig(LoopConfig):
    iterations: int = 60000
    batch: int = 64
    lr: float = 3e-4
    motion_start: float = field(default=0.3, metadata={"help": "motion scale of the curriculum at step 0", "min": 0})
    motion_ramp: int = field(
        default=12000, metadata={"help": "steps over which motion grows to --motion-max", "min": 0}
    )
    motion_max: float = field(default=1.0, metadata={"help": "largest motion scale of the curriculum", "min": 0})
    geometry_weights: tuple[float, float, float, float, float] = field(
        default=(0.2, 0.075, 0.075, 0.15, 0.5),
        metadata={
            "help": "how often each kind of pair is drawn: point clouds seen by two cameras (plane, sphere, cube, "
            "mixed scene) or image points moved by a random 2D homography",
            "metavar": ("PLANE", "SPHERE", "CUBE", "MIXED", "HOMOGRAPHY"),
            "min": 0,
        },
    )
    max_matches: int = 128  # true matches per pair used by the loss
    loss_weighting: LossWeighting = field(
        default="matches",
        metadata={
            "help": "how the pairs of a batch weigh in the loss: matches (the paper's sum over true matches: a "
            "dense pair weighs more) or pairs (each pair's mean error, as in the breakdown evaluation)"
        },
    )
    cauchy: float = field(
        default=0.0,
        metadata={
            "help": "replace each match's squared distance in the loss by the Cauchy loss of this scale, in "
            "normalised coordinates (0.05: about 4 px across a 160 px width; 0: the paper's squared distance)",
            "metavar": "SCALE",
            "min": 0,
        },
    )
    homography: tuple[float, float, float, float] = field(
        default=(0.3, np.pi / 4, 0.35, 0.1),
        metadata={
            "help": "ranges of the 2D homography pairs at full motion: translation and corner jitter as shares of "
            "the image size, rotation in radians, zoom as +- a share",
            "metavar": ("TRANSLATION", "ROTATION", "ZOOM", "JITTER"),
            "min": 0,
        },
    )
    max_extra: float = field(
        default=0.5,
        metadata={
            "help": "each image of a pair gets a random share, up to this one, of its point count in spurious "
            "random points (the breakdown evaluation adds 0, 20 or 40%% to image B)",
            "metavar": "SHARE",
            "min": 0,
            "max": 1,
        },
    )
    clean_a_share: float = field(
        default=0.0,
        metadata={
            "help": "this share of the pairs is drawn as the breakdown evaluation draws them: image A keeps every "
            "point, image B every point still in view plus spurious ones (0: dropout and spurious points in both)",
            "metavar": "SHARE",
            "min": 0,
            "max": 1,
        },
    )

    def __post_init__(self):
        super().__post_init__()
        if self.loss_weighting not in LOSS_WEIGHTINGS:
            raise InputError(
                f"--loss-weighting must be one of {', '.join(LOSS_WEIGHTINGS)}, got {self.loss_weighting!r}"
            )
        if self.cauchy < 0:
            raise InputError(f"--cauchy must be 0 (the squared loss) or a positive scale, got {self.cauchy}")
        self.pairs()  # raises on bad pair options

    def pairs(self, motion: float = 1.0) -> PairConfig:
        """The training pairs' configuration at curriculum ``motion``."""
        return PairConfig(
            motion=motion,
            geometry_weights=tuple(self.geometry_weights),
            homography=HomographyConfig(*self.homography),
            max_extra=self.max_extra,
            clean_a_share=self.clean_a_share,
        )


def motion_at(config: TrainConfig, step: int) -> float:
    progress = min(1.0, step / max(1, config.motion_ramp))
    return config.motion_start + (config.motion_max - config.motion_start) * progress


def make_batch(
    rng: np.random.Generator, batch: int, config: TrainConfig, pairs: PairConfig
) -> tuple[torch.Tensor, ...]:
    """``batch`` pairs: inputs (B, 130, Hc, Wc), normalised true matches (B, M, 2) x2 and their mask (B, M)."""
    samples = [sample_pair(rng, pairs) for _ in range(batch)]
    cells = np.concatenate(
        [
            points_to_cells_batch([s.points_a for s in samples], pairs.size),
            points_to_cells_batch([s.points_b for s in samples], pairs.size),
        ],
        axis=1,
    )
    N = normalizer(pairs.size)
    true = np.zeros((2, batch, config.max_matches, 2), np.float32)
    mask = np.zeros((batch, config.max_matches), bool)
    for b, s in enumerate(samples):
        pick = rng.permutation(len(s.true_a))[: config.max_matches]
        for side, points in enumerate((s.true_a, s.true_b)):
            true[side, b, : len(pick)] = points[pick] @ N[:2, :2].T + N[:2, 2]
        mask[b, : len(pick)] = True
    return (torch.from_numpy(cells), torch.from_numpy(true[0]), torch.from_numpy(true[1]), torch.from_numpy(mask))


def run(out_dir: Path, config: TrainConfig = TrainConfig(), model_config: MagicWarpConfig | None = None) -> dict:
    """Train (or resume) into ``out_dir``; returns the last validation figures. A resumed run keeps
    the network shape of its checkpoint."""
    from deepslam.frontend.evaluation.warp import validation_figures, validation_set

    torch.set_num_threads(config.threads)
    model_config = model_config or MagicWarpConfig()
    if (out_dir / "last.pt").exists():
        model_config = MagicWarpConfig(**read_weights(out_dir / "last.pt")[0])
    with torch.random.fork_rng():  # the initial weights come from the seed, the global generator is left alone
        torch.manual_seed(config.seed)
        model = MagicWarpNet(model_config)
    validation = validation_set(seed=config.seed + 1000)

    def step_fn(step: int, rng: np.random.Generator, batch: int) -> dict:
        motion = motion_at(config, step)
        device = next(model.parameters()).device
        cells, true_a, true_b, mask = (t.to(device) for t in make_batch(rng, batch, config, config.pairs(motion)))
        return {
            "loss": warp_loss(model(cells), true_a, true_b, mask, config.loss_weighting, config.cauchy),
            "motion": torch.tensor(motion),
        }

    return train(model, config, out_dir, step_fn, lambda m: validation_figures(m, validation), "score")
