"""Time on inputs: order checks and TUM's association of ground truth to images."""

from __future__ import annotations

import numpy as np

from deepslam.inputs.source import SourceError

MAX_TIME_GAP_NS = 20_000_000  # ground truth further than this from an image is not associated (TUM's 0.02 s)


def check_order(stamps: list[int], what: str) -> None:
    """Raise ``SourceError`` naming ``what`` unless ``stamps`` (ns) strictly increase."""
    for index, (a, b) in enumerate(zip(stamps, stamps[1:], strict=False)):
        if b <= a:
            raise SourceError(f"{what}: timestamps out of order at frame {index + 1} ({a} then {b} ns)")


def associate(stamps: list[int], truth_stamps: list[int], max_gap_ns: int = MAX_TIME_GAP_NS) -> dict[int, int]:
    """TUM's association of ground truth to images: pairs closest in time first, each used once.

    Args:
        stamps: image stamps (ns).
        truth_stamps: ground-truth stamps (ns).
        max_gap_ns: pairs further apart are not associated.

    Returns:
        {image index: truth index}.

    Example:
        >>> associate([0, 100_000_000], [5_000_000, 90_000_000, 300_000_000])
        {0: 0, 1: 1}
    """
    if not stamps or not truth_stamps:
        return {}
    truth = np.asarray(truth_stamps, np.int64)
    candidates = []
    for i, t in enumerate(stamps):
        near = np.nonzero(np.abs(truth - t) < max_gap_ns)[0]
        candidates += [(abs(int(truth[j]) - t), i, int(j)) for j in near]
    pairs, used = {}, set()
    for _, i, j in sorted(candidates):
        if i not in pairs and j not in used:
            pairs[i] = j
            used.add(j)
    return pairs
