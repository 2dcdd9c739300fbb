"""Training MagicPoint on Synthetic Shapes with homographic warps and full photometric noise."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from torch import nn

from deepslam.errors import InputError
from deepslam.frontend.cells import CELL
from deepslam.frontend.magicpoint import VARIANTS, MagicPointNet
from deepslam.frontend.training.loop import LoopConfig, train
from deepslam.sim.shapes import training_stream


@dataclass(frozen=True)
class TrainConfig(LoopConfig):
    variant: str = field(
        default="S", metadata={"help": "network size (S-HA: `deepslam train magicpoint-ha`)", "choices": ("S", "L")}
    )
    iterations: int = 8000
    validation_per_category: int = field(
        default=20,
        metadata={
            "help": "validation images per Synthetic Shapes category (each clean and noisy)",
            "min": 1,
            "max": 10_000,
        },
    )
    clean_share: float = field(
        default=0.0,
        metadata={"help": "share of training images left without photometric noise", "min": 0, "max": 1},
    )

    def __post_init__(self):
        super().__post_init__()
        if self.variant not in VARIANTS:
            raise InputError(f"--variant must be one of {', '.join(VARIANTS)}, got {self.variant!r}")
        if not 0 <= self.clean_share <= 1:
            raise InputError(f"--clean-share must lie in [0, 1], got {self.clean_share}")


def cell_labels(corners: list[np.ndarray], size: tuple[int, int], rng: np.random.Generator) -> np.ndarray:
    """Cell class targets int64 (B, H/8, W/8): the position (0..63) of a corner in its 8x8 cell, a
    random one where a cell holds several, 64 (dustbin) where it holds none."""
    h, w = size
    labels = np.full((len(corners), h // CELL, w // CELL), CELL * CELL, np.int64)
    for b, points in enumerate(corners):
        pixels = np.clip(np.rint(points).astype(np.int64), 0, [w - 1, h - 1]).reshape(-1, 2)
        for x, y in pixels[rng.permutation(len(pixels))]:
            labels[b, y // CELL, x // CELL] = (y % CELL) * CELL + x % CELL
    return labels


def make_batch(
    stream, rng: np.random.Generator, batch: int, size: tuple[int, int]
) -> tuple[torch.Tensor, torch.Tensor]:
    images, corners = zip(*(next(stream) for _ in range(batch)), strict=False)
    x = torch.from_numpy(np.stack(images)).float().div_(255.0)[:, None]
    return x, torch.from_numpy(cell_labels(list(corners), size, rng))


def run(out_dir: Path, config: TrainConfig = TrainConfig(), size: tuple[int, int] = (120, 160)) -> dict:
    """Train (or resume) into ``out_dir``. Validation: mAP and MLE on a fixed seeded Synthetic Shapes set,
    noisy and clean, extracted as the evaluation does; their mean ("map", both are targets) picks
    ``best.pt``."""
    from deepslam.frontend.config import EXTRACTION_PRESETS
    from deepslam.frontend.evaluation.detector import evaluate_set, noisy_set
    from deepslam.frontend.magicpoint import MagicPoint
    from deepslam.sim.shapes import evaluation_set

    torch.set_num_threads(config.threads)
    with torch.random.fork_rng():  # the initial weights come from the seed, the global generator is left alone
        torch.manual_seed(config.seed)
        model = MagicPointNet(VARIANTS[config.variant])
    clean_validation = evaluation_set(config.validation_per_category, seed=config.seed + 1000, size=size)
    validation = noisy_set(clean_validation, seed=config.seed + 1000)
    loss_fn = nn.CrossEntropyLoss()
    stream = None  # made on the first step, from the (possibly resumed) generator state

    def step_fn(step: int, rng: np.random.Generator, batch: int) -> dict:
        nonlocal stream
        stream = stream or training_stream(rng, size, clean_share=config.clean_share)
        images, labels = make_batch(stream, rng, batch, size)
        device = next(model.parameters()).device
        return {"loss": loss_fn(model(images.to(device)), labels.to(device))}

    def validate(net: MagicPointNet) -> dict:
        detector = MagicPoint(net, EXTRACTION_PRESETS["shapes"])
        noisy, clean = evaluate_set(detector, validation), evaluate_set(detector, clean_validation)
        return {
            "map": (noisy["map"] + clean["map"]) / 2,
            "map_noisy": noisy["map"],
            "mle_noisy": noisy["mle"],
            "map_clean": clean["map"],
            "mle_clean": clean["mle"],
        }

    return train(model, config, out_dir, step_fn, validate, "map")
