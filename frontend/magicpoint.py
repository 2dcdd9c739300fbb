"""MagicPoint: a VGG-style fully convolutional corner detector with a 65-channel cell softmax."""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Literal

import cv2
import numpy as np
import torch
from torch import nn

from deepslam.errors import InputError
from deepslam.frontend.cells import CELL
from deepslam.frontend.config import EXTRACTION_PRESETS, ExtractionConfig
from deepslam.frontend.nets import fold_batchnorm, load_network, pooling, vgg_block
from deepslam.frontend.points import check_image, extract_points

WEIGHTS = Path(__file__).parent / "weights"


@dataclass(frozen=True)
class MagicPointConfig:
    """Encoder widths (two 3x3 VGG blocks per stage; a 2x2 max-pool after each of the first three
    stages), the width of the 3x3 layer before the 1x1 head to 65 channels, and the max-pool: "max" (the
    paper's) or "blur" (anti-aliased, ``nets.BlurMaxPool``: detections follow sub-cell motion more closely)."""

    widths: tuple[int, int, int, int] = (8, 8, 16, 16)
    head: int = 32
    pool: Literal["max", "blur"] = "max"


VARIANTS = {
    "S": MagicPointConfig((8, 8, 16, 16), 32),
    "L": MagicPointConfig((64, 64, 128, 128), 256),
    "S-HA": MagicPointConfig((8, 8, 16, 16), 32, "blur"),  # S on real photographs: homographic adaptation
}


class MagicPointNet(nn.Module):
    """(B, 1, H, W) float image in [0, 1] -> (B, 65, H/8, W/8) logits."""

    def __init__(self, config: MagicPointConfig = VARIANTS["S"]):
        super().__init__()
        self.config = config
        layers, channels = [], 1
        for stage, width in enumerate(config.widths):
            layers += [vgg_block(channels, width), vgg_block(width, width)]
            channels = width
            if stage < 3:
                layers.append(pooling(config.pool))
        self.encoder = nn.Sequential(*layers)
        self.head = nn.Sequential(vgg_block(channels, config.head), nn.Conv2d(config.head, CELL * CELL + 1, 1))

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        return self.head(self.encoder(image))


GRID_SHIFTS = {
    1: [(0, 0)],
    2: [(0, 0), (4, 4)],
    4: [(0, 0), (4, 0), (0, 4), (4, 4)],
}  # (dx, dy) averaged by ``heatmap``
SHIFT_BATCH = 2  # shifted copies per forward pass: 2 ran 1.25-1.45x faster than 1 or 4 on one thread here


def cells_to_heatmap(cells: torch.Tensor) -> torch.Tensor:
    """(B, 65, Hc, Wc) cell softmax -> (B, Hc*8, Wc*8) probabilities: dustbin dropped, depth to space."""
    return nn.functional.pixel_shuffle(cells[:, : CELL * CELL], CELL)[:, 0]


def _as_tensor(image: np.ndarray) -> torch.Tensor:
    image = check_image(image, CELL)
    return torch.from_numpy(image).float().div_(255.0)[None, None]


class MagicPoint:
    """The shipped MagicPoint, ready for inference (BatchNorm folded, eval mode).

    Args:
        net: the network.
        extraction: how points are extracted (``ExtractionConfig``; default: ``EXTRACTION_PRESETS["default"]``).
        device: where the network runs ("cpu" or "cuda").
        **options: fields of ``extraction`` to change, e.g. ``threshold=0.001``.
    """

    def __init__(self, net: MagicPointNet, extraction: ExtractionConfig | None = None, device: str = "cpu", **options):
        self.extraction = replace(extraction or EXTRACTION_PRESETS["default"], **options)
        self.device = torch.device(device)
        self.net = fold_batchnorm(net).to(self.device)

    @classmethod
    def pretrained(
        cls, variant: str = "S", path: str | Path | None = None, device: str = "cpu", **options
    ) -> "MagicPoint":
        """Load the weights shipped in ``frontend/weights`` (no download) or a training checkpoint, with the
        variant's own extraction (``EXTRACTION_PRESETS``) changed by ``options`` (an ``extraction`` config, or
        some of its fields)."""
        if variant not in VARIANTS:
            raise InputError(f"unknown MagicPoint variant {variant!r}; expected one of {', '.join(VARIANTS)}")
        path = Path(path) if path else WEIGHTS / f"magicpoint_{variant}.pt"
        if not path.exists():
            raise FileNotFoundError(f"no MagicPoint weights at {path}; train them with `deepslam train magicpoint`")
        net = load_network(path, MagicPointNet, MagicPointConfig)
        own = options.pop("extraction", None) or EXTRACTION_PRESETS.get(variant, EXTRACTION_PRESETS["default"])
        return cls(net, own, device, **options)

    @torch.inference_mode()
    def cells(self, image: np.ndarray) -> np.ndarray:
        """Cell softmax, float32 (65, H/8, W/8): the input format of MagicWarp."""
        return torch.softmax(self.net(_as_tensor(image).to(self.device)), dim=1)[0].cpu().numpy()

    @torch.inference_mode()
    def heatmap(self, image: np.ndarray) -> np.ndarray:
        """Per-pixel corner probability, float32 (H, W)."""
        if self.extraction.grid_shifts == 1:
            return cells_to_heatmap(torch.softmax(self.net(_as_tensor(image).to(self.device)), dim=1))[0].cpu().numpy()
        image = check_image(image, CELL)
        h, w = image.shape
        shifts = GRID_SHIFTS[self.extraction.grid_shifts]
        batch = np.stack(
            [cv2.copyMakeBorder(image, dy, CELL - dy, dx, CELL - dx, cv2.BORDER_REFLECT_101) for dx, dy in shifts]
        )
        x = torch.from_numpy(batch).float().div_(255.0)[:, None].to(self.device)
        heatmaps = (
            torch.cat([cells_to_heatmap(torch.softmax(self.net(chunk), dim=1)) for chunk in x.split(SHIFT_BATCH)])
            .cpu()
            .numpy()
        )
        return np.mean(
            [heat[dy : dy + h, dx : dx + w] for heat, (dx, dy) in zip(heatmaps, shifts, strict=False)], axis=0
        )

    def detect(self, image: np.ndarray) -> np.ndarray:
        """Corners of one image.

        Args:
            image: uint8 (H, W) grayscale, H and W multiples of 8.

        Returns:
            float32 (N, 3) [x, y, score], sorted by descending score, in the input's pixels.

        Example:
            >>> import numpy as np
            >>> from deepslam.frontend import MagicPoint
            >>> image = np.zeros((120, 160), np.uint8)
            >>> image[40:80, 60:100] = 255  # a bright square: four corners
            >>> points = MagicPoint.pretrained("S-HA").detect(image)
            >>> points.shape[1], len(points) >= 4
            (3, True)
        """
        e = self.extraction
        s = e.upsample
        if s > 1:
            h, w = check_image(image, CELL).shape
            image = cv2.resize(image, (w * s, h * s), interpolation=cv2.INTER_LINEAR)
        points = extract_points(self.heatmap(image), e.threshold, e.nms_radius * s, e.border * s, e.top_k, e.subpixel)
        if s > 1:
            points[:, :2] = (points[:, :2] + 0.5) / s - 0.5  # pixel centres: x_enlarged + 0.5 = s (x + 0.5)
        return points
