"""Polishing correspondences between a keyframe and a later frame.

MagicPoint's detections jitter by a pixel or so from frame to frame, and a few tracks snap to the wrong
detection; both pass a robust homography fit and bend the pose. ``polish`` moves each current point to
where Lucas-Kanade aligns the keyframe's patch around its partner (starting from the tracked position,
no pyramid) and drops the pairs it cannot confirm: moved ``max_move`` pixels or more, or not aligning back
to their partner (a forward-backward check, ``max_return``). It aligns contrast-normalised images
(``normalise_contrast``), so brightness, contrast and shading changes between the two frames do not bias it,
and it first warps the keyframe by the homography the pairs agree on (the dominant plane's), so that the
patches it compares are seen from about the same viewpoint: the scale, rotation and perspective change since
the keyframe would bias it too. A pair it cannot confirm from its tracked position gets a second try from
where the homography of the confirmed pairs puts it (``retry_gate``): a track that snapped to a jittering
detection frame after frame drifts off its point, while its keyframe patch is still there to align.
"""

from __future__ import annotations

import cv2
import numpy as np

from deepslam.frontend.config import DEFAULT_POLISH, PolishConfig
from deepslam.geometry import fit_homography, in_image, warp_points

LK_CRITERIA = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 20, 0.01)
FOLLOW_LEVELS = 1  # pyramid levels above the image ``follow`` aligns on: a prediction may be some pixels off
FOLLOW_RETURN_PX = 1.0  # ``follow``'s forward-backward check (px)


def normalise_contrast(image: np.ndarray, sigma: float = PolishConfig.sigma) -> np.ndarray:
    """uint8 (H, W) image -> uint8 (H, W) of local z-scores (128 + 40 z): the deviation from the Gaussian
    mean of scale ``sigma`` pixels, divided by the local standard deviation (plus 2 grey levels)."""
    pixels = image.astype(np.float32)
    deviation = pixels - cv2.GaussianBlur(pixels, (0, 0), sigma)
    spread = np.sqrt(cv2.GaussianBlur(deviation * deviation, (0, 0), sigma)) + 2.0
    return np.clip(128.0 + 40.0 * deviation / spread, 0, 255).astype(np.uint8)


def plane_warp(reference_points: np.ndarray, current_points: np.ndarray, threshold: float | None) -> np.ndarray | None:
    """The homography (3, 3) most pairs of ``reference_points`` and ``current_points`` (K, 2) agree on
    (MAGSAC, ``threshold`` px), or None: no threshold, fewer than 8 pairs, or no fit."""
    if threshold is None or len(reference_points) < 8:
        return None
    return fit_homography(reference_points, current_points, threshold)


def polish(
    reference: np.ndarray,
    current: np.ndarray,
    reference_points: np.ndarray,
    current_points: np.ndarray,
    config: PolishConfig = DEFAULT_POLISH,
) -> tuple[np.ndarray, np.ndarray]:
    """Align each pair of ``reference_points`` (K, 2) in image ``reference`` and ``current_points`` (K, 2)
    in ``current`` (both from ``normalise_contrast``), the reference warped first by the pairs' homography
    (``plane_warp``), those it cannot confirm again from where the homography of the confirmed ones puts them
    (``_realign``), then check each the other way: the current image warped by the homography of the
    polished pairs, aligned back into the reference. Returns the polished current points (K, 2) float64 and a
    mask (K,) of the pairs Lucas-Kanade confirmed: converged, inside the image, within ``config.max_move``
    pixels of where they started and back close enough to their partners (``config.max_return``)."""
    reference_points = np.asarray(reference_points, np.float64).reshape(-1, 2)
    current_points = np.asarray(current_points, np.float64).reshape(-1, 2)
    moved, confirmed = _align_pairs(reference, current, reference_points, current_points, config)
    if config.retry_gate is not None:
        _realign(reference, current, reference_points, current_points, moved, confirmed, config)
    if config.max_return is not None and confirmed.any():
        partners = reference_points[confirmed]
        back, returned = _align_pairs(current, reference, moved[confirmed], partners, config)
        distance = np.where(returned, np.linalg.norm(back - partners, axis=1), np.inf)
        returned &= distance < max(config.max_return, config.return_scale * float(np.median(distance)))
        confirmed[confirmed] = returned
    return moved, confirmed


def _realign(
    reference: np.ndarray,
    current: np.ndarray,
    reference_points: np.ndarray,
    current_points: np.ndarray,
    moved: np.ndarray,
    confirmed: np.ndarray,
    config: PolishConfig,
) -> None:
    """The second try of ``polish``, in place of ``moved`` (K, 2) and ``confirmed`` (K,): each pair not
    confirmed whose tracked point lies within ``config.retry_gate`` px of where the homography of the confirmed
    pairs (``plane_warp``: at least 8) puts its partner is aligned again from there."""
    if confirmed.all():
        return
    H = plane_warp(reference_points[confirmed], moved[confirmed], config.warp_threshold)
    if H is None:
        return
    start = warp_points(reference_points, H)
    retry = ~confirmed & (np.linalg.norm(start - current_points, axis=1) < config.retry_gate)
    if retry.any():
        moved[retry], confirmed[retry] = _align_pairs(
            reference, current, reference_points[retry], start[retry], config, warp=H
        )


def _align_pairs(
    reference: np.ndarray,
    current: np.ndarray,
    reference_points: np.ndarray,
    current_points: np.ndarray,
    config: PolishConfig,
    warp: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """One direction of ``polish`` (points float64 (K, 2), as ``polish`` makes them): the current points (K, 2)
    Lucas-Kanade moves to from ``current_points`` and the mask (K,) of those it confirmed (converged, inside the
    image, moved less than ``config.max_move`` pixels). The reference is warped by ``warp`` (3, 3), or where None
    by the homography the pairs agree on (``plane_warp``)."""
    if len(reference_points) == 0:
        return np.zeros((0, 2)), np.zeros(0, bool)
    H = warp if warp is not None else plane_warp(reference_points, current_points, config.warp_threshold)
    if H is not None:
        h, w = current.shape
        reference = cv2.warpPerspective(reference, H, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        reference_points = warp_points(reference_points, H)
    moved, confirmed = _lucas_kanade(reference, current, reference_points, current_points, config.window)
    confirmed &= np.linalg.norm(moved - current_points, axis=1) < config.max_move
    confirmed &= in_image(moved, current.shape)
    return moved, confirmed


def _lucas_kanade(
    image: np.ndarray, other: np.ndarray, points: np.ndarray, start: np.ndarray, window: int
) -> tuple[np.ndarray, np.ndarray]:
    """Where Lucas-Kanade (one level, ``window`` px) aligns the patches of ``image`` around ``points`` (K, 2)
    in ``other``, starting from ``start`` (K, 2): positions (K, 2) float64 and a mask (K,) of those it
    converged on."""
    moved, status, _ = cv2.calcOpticalFlowPyrLK(
        image,
        other,
        np.asarray(points, np.float32).reshape(-1, 1, 2),
        np.asarray(start, np.float32).reshape(-1, 1, 2).copy(),
        winSize=(window, window),
        maxLevel=0,
        criteria=LK_CRITERIA,
        flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
    )
    moved = moved.reshape(-1, 2).astype(np.float64)
    return moved, (status.ravel() == 1) & np.all(np.isfinite(moved), axis=1)


def follow(
    previous: np.ndarray,
    current: np.ndarray,
    points: np.ndarray,
    predicted: np.ndarray,
    window: int = DEFAULT_POLISH.window,
    max_return: float = FOLLOW_RETURN_PX,
) -> tuple[np.ndarray, np.ndarray]:
    """Where pyramidal Lucas-Kanade (``window`` px, ``FOLLOW_LEVELS`` levels above the image) aligns the patches of
    image ``previous`` around ``points`` (N, 2) in image ``current`` (both from ``normalise_contrast``), starting
    from ``predicted`` (N, 2), where the motion puts them: positions (N, 2) float64 and a mask (N,) of those it
    found: converged, inside the image and aligning back within ``max_return`` px of their point."""
    points = np.asarray(points, np.float32).reshape(-1, 1, 2)
    if len(points) == 0:
        return np.zeros((0, 2)), np.zeros(0, bool)
    options = dict(
        winSize=(window, window), maxLevel=FOLLOW_LEVELS, criteria=LK_CRITERIA, flags=cv2.OPTFLOW_USE_INITIAL_FLOW
    )
    start = np.asarray(predicted, np.float32).reshape(-1, 1, 2).copy()
    found, status, _ = cv2.calcOpticalFlowPyrLK(previous, current, points, start, **options)
    back, status_back, _ = cv2.calcOpticalFlowPyrLK(current, previous, found, points.copy(), **options)
    found = found.reshape(-1, 2).astype(np.float64)
    returned = np.linalg.norm((back - points).reshape(-1, 2), axis=1)
    good = (status.ravel() == 1) & (status_back.ravel() == 1) & np.all(np.isfinite(found), axis=1)
    good &= (returned < max_return) & in_image(np.nan_to_num(found), current.shape, margin=0.5)
    return found, good
