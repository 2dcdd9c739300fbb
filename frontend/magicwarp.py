"""MagicWarp: a homography from two point images, and descriptor-free matching with it."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np
import torch
from scipy.spatial import cKDTree
from torch import nn

from deepslam.errors import InputError
from deepslam.frontend.cells import CELL, points_to_cells_batch
from deepslam.frontend.config import MagicWarpConfig
from deepslam.frontend.nets import fold_batchnorm, load_network, vgg_block
from deepslam.geometry import fit_homography, in_image, warp_points
from deepslam.interrupts import checkpoint

WEIGHTS = Path(__file__).parent / "weights"
MIN_POINTS = 4  # a homography needs four distinct points; fewer in either image and MagicWarp declines
SUPPORT_PX = 3.0  # a point of image a warped within this of a point of b supports the homography
MIN_SUPPORT = 0.4  # the share of points (of the smaller set) a homography needs; unrelated sets reach about 0.2


class DegeneratePoints(InputError):
    """Point sets MagicWarp cannot relate: too few distinct points, or no overlap under its homography."""


class MagicWarpNet(nn.Module):
    """(B, 130, Hc, Wc) concatenated cell tensors -> (B, 3, 3) homography in normalised coordinates
    ([-1, 1] over pixel centres), ``H[2, 2] == 1``."""

    def __init__(self, config: MagicWarpConfig = MagicWarpConfig()):
        super().__init__()
        self.config = config
        layers, channels = [], 2 * (CELL * CELL + 1)
        for stage in range(0, len(config.widths), config.blocks):
            for width in config.widths[stage : stage + config.blocks]:
                layers.append(vgg_block(channels, width))
                channels = width
            layers.append(nn.MaxPool2d(2))
        self.encoder = nn.Sequential(*layers[:-1], nn.AdaptiveAvgPool2d(config.pooled))
        self.head = nn.Sequential(
            nn.Flatten(),
            nn.Linear(channels * config.pooled[0] * config.pooled[1], config.hidden),
            nn.ReLU(inplace=True),
            nn.Linear(config.hidden, 9),
        )
        last = self.head[-1]
        nn.init.normal_(last.weight, std=1e-3)
        with torch.no_grad():
            last.bias.copy_(torch.eye(3).flatten())

    def forward(self, cells: torch.Tensor) -> torch.Tensor:
        H = self.head(self.encoder(cells)).view(-1, 3, 3)
        return H / H[:, 2:3, 2:3]


def normalizer(size: tuple[int, int]) -> np.ndarray:
    """N (3, 3) mapping pixel coordinates of an image of ``size`` (H, W) to [-1, 1]."""
    h, w = size
    return np.array([[2 / (w - 1), 0, -1], [0, 2 / (h - 1), -1], [0, 0, 1]])


def _as_points(points: np.ndarray, name: str) -> np.ndarray:
    points = np.asarray(points, np.float64)
    if points.ndim != 2 or points.shape[1] not in (2, 3):
        raise InputError(f"{name} must be an (N, 2) or (N, 3) array of (x, y[, score]), got shape {points.shape}")
    return points[:, :2]


class MagicWarp:
    """The shipped MagicWarp, ready for inference (BatchNorm folded, eval mode)."""

    def __init__(self, net: MagicWarpNet, device: str = "cpu"):
        self.device = torch.device(device)
        self.net = fold_batchnorm(net).to(self.device)

    @classmethod
    def pretrained(cls, path: str | Path | None = None, device: str = "cpu") -> "MagicWarp":
        """Load the weights shipped in ``frontend/weights`` (no download) or a training checkpoint."""
        path = Path(path) if path else WEIGHTS / "magicwarp.pt"
        if not path.exists():
            raise FileNotFoundError(f"no MagicWarp weights at {path}; train them with `deepslam train magicwarp`")
        return cls(load_network(path, MagicWarpNet, MagicWarpConfig), device)

    @torch.inference_mode()
    def estimate_batch(self, pairs: list[tuple[np.ndarray, np.ndarray]], image_size: tuple[int, int]) -> np.ndarray:
        """Homographies (B, 3, 3) float64 in pixels for several (points_a, points_b) pairs at once."""
        cells = np.concatenate(
            [
                points_to_cells_batch([a for a, _ in pairs], image_size),
                points_to_cells_batch([b for _, b in pairs], image_size),
            ],
            axis=1,
        )
        x = torch.from_numpy(cells).to(self.device).contiguous(memory_format=torch.channels_last)
        H = self.net(x).double().cpu().numpy()
        N = normalizer(image_size)
        H = np.linalg.inv(N) @ H @ N
        return H / H[:, 2:3, 2:3]

    def estimate(
        self,
        points_a: np.ndarray,
        points_b: np.ndarray,
        image_size: tuple[int, int] = (120, 160),
        iterations: int = 1,
        min_support: float = MIN_SUPPORT,
    ) -> np.ndarray:
        """The homography between two point images, regressed by the network.

        Args:
            points_a: (N, 2+) pixels (x, y) of image a (extra columns, such as scores, are ignored).
            points_b: (M, 2+) pixels of image b.
            image_size: (H, W) of both images.
            iterations: with more than 1, ``points_a`` are warped by the estimate so far, estimated again
                and composed (the paper's H = H2 H1 applied to a).
            min_support: the share of points (of the smaller set) that must lie within ``SUPPORT_PX`` of a
                partner under the homography (0: any homography; the tracker, which refines it, asks none).

        Returns:
            ``H_ab`` (3, 3) float64 mapping pixels of a to b, ``H[2, 2] == 1``. ``InputError`` for another
            shape, non-finite coordinates or points outside the image; ``DegeneratePoints`` for fewer than
            ``MIN_POINTS`` distinct points in either image or sets the homography does not relate: no
            homography is invented.

        Example:
            >>> import numpy as np
            >>> from deepslam.frontend import MagicWarp
            >>> points = np.random.default_rng(0).uniform([10, 10], [150, 110], (60, 2))
            >>> H = MagicWarp.pretrained().estimate(points, points + [4.0, 0.0])  # 4 px to the right
            >>> bool(abs(H[0, 2] - 4) < 3 and H[2, 2] == 1)
            True
        """
        if iterations < 1:
            raise InputError(f"iterations must be at least 1, got {iterations}")
        points_a, points_b = _as_points(points_a, "points_a"), _as_points(points_b, "points_b")
        for name, points in (("points_a", points_a), ("points_b", points_b)):
            if not np.all(np.isfinite(points)):
                raise InputError(f"{name} holds non-finite coordinates")
            outside = int((~in_image(points, image_size)).sum())
            if outside:
                raise InputError(f"{name}: {outside} points lie outside the {image_size[0]}x{image_size[1]} image")
        distinct = [len(np.unique(np.round(p, 2), axis=0)) for p in (points_a, points_b)]
        if min(distinct) < MIN_POINTS:
            raise DegeneratePoints(
                f"MagicWarp needs at least {MIN_POINTS} points in each image, all distinct; got {distinct[0]} and "
                f"{distinct[1]} distinct"
            )
        H = np.eye(3)
        for _ in range(iterations):
            checkpoint()  # Ctrl-C and SIGTERM take effect between iterations
            H = self.estimate_batch([(warp_points(points_a, H), points_b)], image_size)[0] @ H
            H /= H[2, 2]
        supported = support(points_a, points_b, H) if min_support > 0 else 1.0  # the tracker asks none: no k-d tree
        if supported < min_support:
            raise DegeneratePoints(
                f"the point sets do not overlap under MagicWarp's homography: {supported:.0%} of the points lie "
                f"within {SUPPORT_PX:g} px of a partner (at least {min_support:.0%} needed)"
            )
        return H


def refine(
    points_a: np.ndarray,
    points_b: np.ndarray,
    guesses: np.ndarray | Sequence[np.ndarray],
    radii: tuple[float, ...] = (8.0, 3.0),
    threshold: float = 1.5,
) -> np.ndarray:
    """Refine a homography (3, 3) mapping a to b by snapping and a robust fit, still without descriptors.

    ``guesses`` is one homography (3, 3) or several (for example MagicWarp's estimate, the previous
    frame's and the identity). At the first radius (pixels) the points of a, warped by every guess, are
    paired with their nearest points of b (``match``), and one homography is fitted to all those pairs with
    OpenCV's USAC MAGSAC (``threshold`` pixels): the pairs of the guess most points agree with form the
    consensus, the others are its outliers. Each later radius snaps by the fitted homography and fits again.
    When fewer than 8 pairs are found or a fit fails, the homography so far stands (before the first fit:
    the guess most points of a snap to within ``threshold`` pixels, the first on ties).
    """
    a, b = _as_points(points_a, "points_a"), _as_points(points_b, "points_b")
    current = [guesses] if isinstance(guesses, np.ndarray) and guesses.ndim == 2 else list(guesses)
    if not current:
        raise InputError("refine needs at least one guess")
    for radius in radii:
        pairs = _each_once([match(a, b, H, radius) for H in current], len(b))
        if len(pairs) < 8:
            break
        fitted = fit_homography(a[pairs[:, 0]], b[pairs[:, 1]], threshold)
        if fitted is None:
            break
        current = [fitted]
    support = [len(match(a, b, H, threshold)) for H in current] if len(current) > 1 else [0]
    return current[int(np.argmax(support))]


def _each_once(pairs: list[np.ndarray], count_b: int) -> np.ndarray:
    """The index pairs (K, 2) of one or several ``match`` results: one as it is, several each pair once,
    ordered by (i, j) (``np.unique`` over the rows, done on i * ``count_b`` + j: far faster)."""
    if len(pairs) == 1:
        return pairs[0]
    return np.stack(np.divmod(np.unique(np.vstack(pairs) @ np.array([count_b, 1])), count_b), 1)


def support(points_a: np.ndarray, points_b: np.ndarray, H: np.ndarray) -> float:
    """The share of points of the smaller set that ``H`` (3, 3) relates: points of a (N, 2) warped within
    ``SUPPORT_PX`` of a point of b (M, 2), over min(N, M)."""
    distances, _ = cKDTree(points_b).query(warp_points(points_a, H), distance_upper_bound=SUPPORT_PX)
    return float(np.isfinite(distances).sum() / max(min(len(points_a), len(points_b)), 1))


def match(points_a: np.ndarray, points_b: np.ndarray, H: np.ndarray, max_dist: float = 4.0) -> np.ndarray:
    """Correspondences without descriptors: warp ``points_a`` by ``H`` into b and snap each to its nearest
    point of b.

    Pairs are taken in order of increasing distance (ties by index in a, then in b), each point used at
    most once (mutually exclusive); pairs farther apart than ``max_dist`` pixels are not matches. The
    candidates within ``max_dist`` come from k-d trees (scipy), not an (N, M) distance matrix.

    Args:
        points_a: (N, 2) or (N, 3) pixels (x, y[, score]) of image a.
        points_b: (M, 2) or (M, 3) pixels of image b.
        H: ``H_ab`` (3, 3).
        max_dist: the largest distance (px) of a match.

    Returns:
        int64 (K, 2): indices into ``points_a`` and ``points_b``.

    Example:
        >>> import numpy as np
        >>> a = np.array([[10.0, 10.0], [50.0, 20.0]])
        >>> match(a, a[::-1] + 1.0, np.eye(3)).tolist()
        [[0, 1], [1, 0]]
    """
    a, b = _as_points(points_a, "points_a"), _as_points(points_b, "points_b")
    H = np.asarray(H, np.float64)
    if H.shape != (3, 3) or not np.all(np.isfinite(H)):
        raise InputError(f"H must be a finite (3, 3) homography, got shape {H.shape}")
    if not max_dist >= 0 or not np.isfinite(max_dist):
        raise InputError(f"max_dist must be a finite distance of at least 0 px, got {max_dist}")
    if len(a) == 0 or len(b) == 0:
        return np.zeros((0, 2), np.int64)
    near = cKDTree(warp_points(a, H)).sparse_distance_matrix(cKDTree(b), max_dist, output_type="ndarray")
    order = np.lexsort((near["j"], near["i"], near["v"]))
    used_a, used_b = np.zeros(len(a), bool), np.zeros(len(b), bool)
    pairs = []
    for i, j in zip(near["i"][order].tolist(), near["j"][order].tolist(), strict=True):
        if not (used_a[i] or used_b[j]):
            used_a[i] = used_b[j] = True
            pairs.append((i, j))
    return np.array(pairs, np.int64).reshape(-1, 2)
