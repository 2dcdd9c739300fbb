"""The 65-channel cell encoding of point sets (MagicPoint's output format, MagicWarp's input).

A (65, H/8, W/8) tensor: channel ``8 * row + col`` of a cell holds the point at that pixel of the
8x8 cell, channel 64 is the dustbin ("no point"). A cell with k points spreads its mass 1/k over
them, so every cell is a distribution.
"""

from __future__ import annotations

import numpy as np

from deepslam.errors import InputError
from deepslam.geometry import in_image

CELL = 8


def points_to_cells(points: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Encode (N, 2+) points (x, y, ...) of an image of ``size`` (H, W) as float32 (65, H/8, W/8)."""
    return points_to_cells_batch([points], size)[0]


def points_to_cells_batch(point_sets: list[np.ndarray], size: tuple[int, int]) -> np.ndarray:
    """Encode several point sets at once; returns float32 (B, 65, H/8, W/8)."""
    h, w = size
    if h % CELL or w % CELL:
        raise InputError(f"image size must be divisible by {CELL}, got {size}")
    hc, wc = h // CELL, w // CELL
    cells = np.zeros((len(point_sets), CELL * CELL + 1, hc, wc), np.float32)
    counts = np.zeros((len(point_sets), hc, wc), np.float32)
    for b, points in enumerate(point_sets):
        points = np.asarray(points, np.float64)
        if points.size == 0:
            continue
        pixels = np.rint(points.reshape(len(points), -1)[:, :2]).astype(np.int64)
        keep = in_image(pixels, size, margin=0.5)
        x, y = pixels[keep, 0], pixels[keep, 1]
        np.add.at(cells[b], ((y % CELL) * CELL + x % CELL, y // CELL, x // CELL), 1.0)
        np.add.at(counts[b], (y // CELL, x // CELL), 1.0)
    occupied = counts > 0
    cells[:, : CELL * CELL] /= np.where(occupied, counts, 1.0)[:, None]
    cells[:, CELL * CELL] = ~occupied
    return cells
