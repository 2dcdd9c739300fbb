"""Two-view relative pose from point correspondences, with OpenCV (default) or pycolmap.

Models: a homography (planar scenes; decomposed with ``cv2.decomposeHomographyMat`` and the
physically valid solution chosen) or an essential matrix (``cv2.recoverPose``); "auto" scores both
as ORB-SLAM does for every pair of frames, takes the homography when R_H = S_H / (S_H + S_F) > 0.45, and
else the essential matrix if its pose explains clearly more pairs than the homography; either way the
essential matrix wins where pairs off the homography's plane show its pose explains the pairs' epipolar
geometry several times better (a room's second wall, seen over a short baseline).

The result ``T_c1_c2`` is the pose of camera 2 in camera 1's frame (X_1 = T_c1_c2 X_2), the
between-measurement of a pose graph. Monocular translation has no scale: it is a unit vector,
or, for the homography, ``t / d`` with d the distance of camera 1 to the plane.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from deepslam.backend.config import METHODS, MIN_MATCHES
from deepslam.errors import InputError
from deepslam.geometry import vector_angle
from deepslam.interrupts import import_pycolmap

STATIC_FLOW_PX = 0.3  # a median flow below this (px): no motion
MIN_INLIER_RATIO = 0.3  # a model that explains a smaller share of the matches is not trusted ...
MIN_INLIERS = 10  # ... nor one that explains fewer pairs than this (8 determine E and H exactly; noise needs more)
AMBIGUOUS_DEG = 30.0  # a homography's and an essential matrix's translations this far apart ...
AMBIGUOUS_SHARE = 0.1  # ... while E explains as many pairs (within this share): plane or not, the pairs cannot tell
MIN_SPREAD_PX = 2.0  # matched points whose second principal spread is below this (px) are collinear
ROTATION_ONLY_PX = 0.5  # E: if K R K^-1 alone maps p1 onto p2 this closely (median px), translation is unobservable
CHI2_1DOF_95 = 3.84  # chi-square 95% quantiles: one degree of freedom (point-to-line) ...
CHI2_2DOF_95 = 5.99  # ... and two (point-to-point); ORB-SLAM's model-selection thresholds
HOMOGRAPHY_RATIO = 0.45  # ORB-SLAM: the homography wins when R_H = S_H / (S_H + S_F) is above this
ESSENTIAL_MARGIN = 0.1  # "auto" keeps E only if its pose explains this share of the pairs more than H does
EPIPOLAR_GAIN = 3.0  # ... or if the pairs' epipolar residual under its pose is this many times smaller than under H's
OFF_PLANE_PX = 1.0  # ... and OFF_PLANE_MARGIN of its inliers are this far (px) from where the homography takes them
EPIPOLAR_PX = 1.5  # a pair's Sampson distance (px) below this: the pair fits an epipolar geometry
OFF_PLANE_MARGIN = 5  # a homography's decomposition wins outright by fitting this many more pairs off its plane
SAME_PLANE_DEG = 20.0  # a decomposition whose normal is this close to the plane seen before is that plane ...
PLANE_MARGIN_DEG = 15.0  # ... when the other decompositions' normals are at least this much farther from it
ESSENTIAL_FITS = (cv2.USAC_MAGSAC, cv2.RANSAC, cv2.LMEDS)  # robust fits of E, the one explaining most pairs kept
QUICK_FITS = (cv2.USAC_MAGSAC, cv2.RANSAC)  # ... where the scores chose H and E is only checked (LMedS: ~20 ms)
VISIBLE_SHARE = 0.9  # a decomposition is valid if this share of its plane's points is in front of both cameras


@dataclass
class RelativePose:
    """T_c1_c2 (4, 4) with |t| = 1 (or t/d for a homography); ``model`` is "homography", "essential",
    "static" (no motion), "pnp" (located in a map: T metric, the odometry's), or "failed" (then T is the
    identity); ``inliers`` (N,) bool;
    ``plane_normal`` n (n . X_1 = d on the plane) and ``t_over_d`` |t| / d of the homography (also
    filled from the dominant plane for essential poses when metric scale comes from it);
    ``reason`` explains failures and degenerate cases."""

    T_c1_c2: np.ndarray
    model: str
    inliers: np.ndarray
    rotation_only: bool = False
    plane_normal: np.ndarray | None = None
    t_over_d: float | None = None
    reason: str = ""

    @property
    def ok(self) -> bool:
        return self.model in ("homography", "essential", "static", "pnp")

    @property
    def inlier_ratio(self) -> float:
        return float(self.inliers.mean()) if len(self.inliers) else 0.0


def _between(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """T_c1_c2 from OpenCV's X_2 = R X_1 + t."""
    T = np.eye(4)
    T[:3, :3] = R.T
    T[:3, 3] = -R.T @ np.ravel(t)
    return T


def _normalised(points: np.ndarray, K: np.ndarray) -> np.ndarray:
    return cv2.undistortPoints(points.reshape(-1, 1, 2).astype(np.float64), K, None).reshape(-1, 2)


def _transfer_px(H: np.ndarray, p1: np.ndarray, p2: np.ndarray) -> np.ndarray:
    """Distances (N,) in pixels from where the homography H (3, 3) takes p1 (N, 2) to p2 (N, 2)."""
    return np.linalg.norm(cv2.perspectiveTransform(p1.reshape(-1, 1, 2), H).reshape(-1, 2) - p2, axis=1)


def _score_homography(H: np.ndarray, p1: np.ndarray, p2: np.ndarray, sigma: float) -> tuple[float, np.ndarray]:
    """ORB-SLAM's S_H: symmetric transfer error with chi-square threshold ``CHI2_2DOF_95``."""
    e12, e21 = (_transfer_px(M, a, b) ** 2 / sigma**2 for M, a, b in ((H, p1, p2), (np.linalg.inv(H), p2, p1)))
    score = np.where(e12 < CHI2_2DOF_95, CHI2_2DOF_95 - e12, 0) + np.where(e21 < CHI2_2DOF_95, CHI2_2DOF_95 - e21, 0)
    return float(score.sum()), (e12 < CHI2_2DOF_95) & (e21 < CHI2_2DOF_95)


def _score_fundamental(F: np.ndarray, p1: np.ndarray, p2: np.ndarray, sigma: float) -> tuple[float, np.ndarray]:
    """ORB-SLAM's S_F: distances to epipolar lines, threshold ``CHI2_1DOF_95``, score offset ``CHI2_2DOF_95``."""
    h1, h2 = np.c_[p1, np.ones(len(p1))], np.c_[p2, np.ones(len(p2))]
    l2, l1 = h1 @ F.T, h2 @ F
    num = np.sum(h2 * l2, 1) ** 2
    e2 = num / (l2[:, 0] ** 2 + l2[:, 1] ** 2 + 1e-12) / sigma**2
    e1 = num / (l1[:, 0] ** 2 + l1[:, 1] ** 2 + 1e-12) / sigma**2
    score = np.where(e2 < CHI2_1DOF_95, CHI2_2DOF_95 - e2, 0) + np.where(e1 < CHI2_1DOF_95, CHI2_2DOF_95 - e1, 0)
    return float(score.sum()), (e1 < CHI2_1DOF_95) & (e2 < CHI2_1DOF_95)


def homography_pose(
    p1: np.ndarray,
    p2: np.ndarray,
    K: np.ndarray,
    H: np.ndarray | None = None,
    previous_t: np.ndarray | None = None,
    inliers: np.ndarray | None = None,
    previous_normal: np.ndarray | None = None,
) -> RelativePose:
    """Relative pose from a homography (estimated with MAGSAC if not given; a given one with its
    ``inliers`` (N,) among the pairs, all of them when None) and its decomposition.

    Of the up to four solutions, keep those with ``VISIBLE_SHARE`` of the inliers in front of both cameras
    (``_visible_shares``: a few inliers may lie off the plane) and the plane facing camera 1.
    Two usually remain, and the plane's own points cannot tell them apart; the pairs off the plane (a
    room's other walls) can: take the solution whose epipolar geometry fits ``OFF_PLANE_MARGIN`` more of
    them than any other; else the one whose plane normal is the plane seen before, ``previous_normal``
    (unit (3,) in camera 1; within ``SAME_PLANE_DEG`` of it and ``PLANE_MARGIN_DEG`` closer than the
    others: a wall does not turn, a path does); else, of those with the most inliers in front of both
    cameras, the one whose translation agrees best with ``previous_t`` (else the first).
    """
    if H is None:
        H, mask = cv2.findHomography(p1, p2, cv2.USAC_MAGSAC, 1.5, maxIters=2000, confidence=0.999)
        if H is None:
            return _failed(len(p1), "homography estimation failed")
        inliers = mask.ravel().astype(bool)
    inliers = np.ones(len(p1), bool) if inliers is None else inliers
    solutions = _finite_decompositions(H, K)
    if not solutions:  # OpenCV's closed form divides by zero on some exact homographies (noise-free matches)
        return _failed(len(p1), "the homography's decomposition is not finite")
    rotations, translations, normals = solutions
    visible = _visible_shares(rotations, normals, _normalised(p1[inliers], K), _normalised(p2[inliers], K))
    candidates = _in_front(visible, normals)
    rotation_only = max(np.linalg.norm(translations[i]) for i in candidates) < 1e-3
    if not rotation_only:
        candidates = _fitting_off_plane(candidates, rotations, translations, p1[~inliers], p2[~inliers], K)
        if previous_normal is not None and len(candidates) > 1:
            same = _same_plane([normals[i].ravel() for i in candidates], previous_normal)
            candidates = [candidates[same]] if same is not None else candidates
    most = max(visible[i] for i in candidates)  # undecided: the solutions with the most points in front
    candidates = [i for i in candidates if visible[i] == most]
    if previous_t is not None and not rotation_only:
        candidates = _along(candidates, rotations, translations, previous_t)
    best = candidates[0]
    return RelativePose(
        _between(rotations[best], translations[best]),
        "homography",
        inliers,
        rotation_only,
        normals[best].ravel(),
        float(np.linalg.norm(translations[best])),
    )


def _in_front(visible: list[float], normals: list) -> list[int]:
    """The decompositions with ``VISIBLE_SHARE`` of the inliers in front of both cameras (``visible``), then of
    those the ones whose plane faces camera 1 (OpenCV's normal satisfies n . X_1 = d > 0 on the plane, so a
    plane in front of camera 1 has n_z > 0); where none passes a test, all that were left before it."""
    candidates = [i for i in range(len(visible)) if visible[i] >= VISIBLE_SHARE] or list(range(len(visible)))
    return [i for i in candidates if normals[i].ravel()[2] > 0] or candidates


def _finite_decompositions(H: np.ndarray, K: np.ndarray) -> tuple[list, list, list] | None:
    """OpenCV's decompositions of H (3, 3) given K: rotations (3, 3), translations (3, 1) over the plane's
    distance and plane normals (3, 1) in camera 1, of the solutions that are finite; None if none is."""
    count, *solutions = cv2.decomposeHomographyMat(H, K)
    finite = [i for i in range(count) if all(np.isfinite(part[i]).all() for part in solutions)]
    if not finite:
        return None
    rotations, translations, normals = ([part[i] for i in finite] for part in solutions)
    return rotations, translations, normals


def _fitting_off_plane(
    candidates: list[int], rotations: list, translations: list, off1: np.ndarray, off2: np.ndarray, K: np.ndarray
) -> list[int]:
    """``candidates`` ordered by how many pairs off the plane, ``off1`` -> ``off2`` (N, 2) px, fit their
    epipolar geometry; only the first where it fits ``OFF_PLANE_MARGIN`` more than any other."""
    if len(candidates) < 2:
        return candidates
    fits = {i: _off_plane_fits(rotations[i], translations[i], off1, off2, K) for i in candidates}
    candidates = sorted(candidates, key=lambda i: fits[i], reverse=True)
    return candidates[:1] if fits[candidates[0]] - fits[candidates[1]] >= OFF_PLANE_MARGIN else candidates


def _along(candidates: list[int], rotations: list, translations: list, previous_t: np.ndarray) -> list[int]:
    """``candidates`` ordered by how well camera 2's direction from camera 1 agrees with ``previous_t`` (3,)."""

    def agreement(i):  # X_2 = R X_1 + t: camera 2's centre in frame 1 is -R^T t; compare directions
        centre = -rotations[i].T @ translations[i].ravel()
        return float(centre @ previous_t / (np.linalg.norm(centre) * np.linalg.norm(previous_t) + 1e-12))

    return sorted(candidates, key=agreement, reverse=True)


def _visible_shares(
    rotations: tuple[np.ndarray, ...], normals: tuple[np.ndarray, ...], n1: np.ndarray, n2: np.ndarray
) -> list[float]:
    """For each decomposition (R, n) of a homography, the share of its inliers, at normalised points n1 -> n2
    (K, 2), that lie in front of both cameras on its plane: n . m1 > 0 and (R n) . m2 > 0. OpenCV's
    ``filterHomographyDecompByVisibleRefpoints`` asks this of every point, so that one pair off the plane
    that still fits the homography over a short baseline (a room's other wall) can rule out the true
    solution; a share tolerates it."""
    m1, m2 = np.c_[n1, np.ones(len(n1))], np.c_[n2, np.ones(len(n2))]
    shares = []
    for R, n in zip(rotations, normals, strict=True):
        in_front = (m1 @ n.ravel() > 0) & (m2 @ (R @ n.ravel()) > 0)
        shares.append(float(in_front.mean()) if len(in_front) else 1.0)
    return shares


def _same_plane(normals: list[np.ndarray], previous: np.ndarray) -> int | None:
    """Index of the one normal (unit (3,)) within ``SAME_PLANE_DEG`` of ``previous`` and ``PLANE_MARGIN_DEG``
    closer to it than any other; None if there is no such clear choice."""
    angles = np.degrees(vector_angle(np.array(normals), previous))
    order = np.argsort(angles)
    if angles[order[0]] <= SAME_PLANE_DEG and angles[order[1]] - angles[order[0]] >= PLANE_MARGIN_DEG:
        return int(order[0])
    return None


def _pose_sampson_px(R: np.ndarray, t: np.ndarray, p1: np.ndarray, p2: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Sampson distances (N,) in pixels of pairs p1 -> p2 (N, 2) to the epipolar geometry of X_2 = R X_1 + t."""
    tx, ty, tz = np.ravel(t)
    t_cross = np.array([[0.0, -tz, ty], [tz, 0.0, -tx], [-ty, tx, 0.0]])
    return _sampson_px(t_cross @ R, p1, p2, K)


def _off_plane_fits(R: np.ndarray, t: np.ndarray, p1: np.ndarray, p2: np.ndarray, K: np.ndarray) -> int:
    """How many pairs p1 -> p2 (N, 2) px, off the homography's plane, fit the epipolar geometry of
    X_2 = R X_1 + t (Sampson distance below ``EPIPOLAR_PX``)."""
    if len(p1) == 0:
        return 0
    return int(np.sum(_pose_sampson_px(R, t, p1, p2, K) < EPIPOLAR_PX))


def _epipolar_residual(pose: RelativePose, p1: np.ndarray, p2: np.ndarray, K: np.ndarray) -> float:
    """Mean squared Sampson distance (px^2, each capped at ``EPIPOLAR_PX``) of all pairs p1 -> p2 (N, 2) to
    the epipolar geometry of ``pose``: how well its motion explains the pairs on and off any plane."""
    T_c2_c1 = np.linalg.inv(pose.T_c1_c2)
    distances = _pose_sampson_px(T_c2_c1[:3, :3], T_c2_c1[:3, 3], p1, p2, K)
    return float(np.mean(np.minimum(distances, EPIPOLAR_PX) ** 2))


def _sampson_px(E: np.ndarray, p1: np.ndarray, p2: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Sampson distances (N,) in pixels of matches p1 -> p2 to the epipolar geometry of E."""
    K_inv = np.linalg.inv(K)
    F = K_inv.T @ E @ K_inv
    h1, h2 = np.c_[p1, np.ones(len(p1))], np.c_[p2, np.ones(len(p2))]
    Fx1, Ftx2 = h1 @ F.T, h2 @ F
    num = np.sum(h2 * Fx1, 1) ** 2
    return np.sqrt(num / (Fx1[:, 0] ** 2 + Fx1[:, 1] ** 2 + Ftx2[:, 0] ** 2 + Ftx2[:, 1] ** 2 + 1e-12))


def essential_pose(
    p1: np.ndarray,
    p2: np.ndarray,
    K: np.ndarray,
    threshold: float = EPIPOLAR_PX,
    fits: tuple[int, ...] = ESSENTIAL_FITS,
) -> RelativePose:
    """Relative pose from an essential matrix and ``cv2.recoverPose`` (cheirality).

    Scenes dominated by a plane, seen over a short baseline, make E nearly degenerate: a robust fit can
    lock onto the plane and explain only its points. So E is fitted by each of ``fits`` (OpenCV's robust
    methods; by default MAGSAC, RANSAC and LMedS) and the solution whose pose explains the most matches
    (Sampson distance below ``threshold`` pixels, in front of both cameras) is kept. A camera that only
    turned gets ``rotation_only_pose``.
    """
    rotation = rotation_only_pose(p1, p2, K)
    if rotation is not None:
        return rotation
    best: RelativePose | None = None
    for method in fits:
        E, _ = cv2.findEssentialMat(p1, p2, K, method, 0.999, 1.0)
        if E is None or E.shape != (3, 3):
            continue
        support = (_sampson_px(E, p1, p2, K) < threshold).astype(np.uint8)[:, None]
        _, R, t, mask = cv2.recoverPose(E, p1, p2, K, mask=support.copy())
        inliers = mask.ravel() > 0
        if best is None or inliers.sum() > best.inliers.sum():
            best = RelativePose(_between(R, t), "essential", inliers)
    if best is None:
        return _failed(len(p1), "essential matrix estimation failed")
    if best.inliers.sum() < MIN_MATCHES:
        return _failed(len(p1), f"only {best.inliers.sum()} points passed the cheirality check")
    return best


def rotation_only_pose(p1: np.ndarray, p2: np.ndarray, K: np.ndarray) -> RelativePose | None:
    """The pose of a camera that only turned, if a rotation explains the matches: the rotation nearest
    to K^-1 H K of a robust homography H, accepted when K R K^-1 maps p1 onto p2 within
    ``ROTATION_ONLY_PX`` (median). Then E is undefined and its translation would be noise; None otherwise."""
    H, mask = cv2.findHomography(p1, p2, cv2.USAC_MAGSAC, 1.5, maxIters=2000, confidence=0.999)
    if H is None:
        return None
    M = np.linalg.inv(K) @ H @ K
    U, _, Vt = np.linalg.svd(M / np.cbrt(np.linalg.det(M)))
    R_21 = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    moved = cv2.perspectiveTransform(p1.reshape(-1, 1, 2), K @ R_21 @ np.linalg.inv(K)).reshape(-1, 2)
    if np.median(np.linalg.norm(moved - p2, axis=1)) >= ROTATION_ONLY_PX:
        return None
    pose = RelativePose(_between(R_21, np.zeros(3)), "essential", mask.ravel().astype(bool), rotation_only=True)
    pose.reason = "pure rotation: the translation is unobservable"
    return pose


def pycolmap_pose(
    p1: np.ndarray, p2: np.ndarray, K: np.ndarray, size: tuple[int, int], max_error: float = 1.0
) -> RelativePose:
    """Relative pose from pycolmap's calibrated two-view geometry (its own model selection);
    ``max_error`` is its RANSAC threshold in pixels."""
    pycolmap = import_pycolmap()

    h, w = size
    # COLMAP puts the centre of the top-left pixel at (0.5, 0.5): shift points and principal point
    camera = pycolmap.Camera(
        model="PINHOLE", width=w, height=h, params=[K[0, 0], K[1, 1], K[0, 2] + 0.5, K[1, 2] + 0.5]
    )
    camera.has_prior_focal_length = True
    options = pycolmap.TwoViewGeometryOptions()
    options.compute_relative_pose = True
    options.ransac.max_error = max_error
    matches = np.repeat(np.arange(len(p1))[:, None], 2, 1)
    geometry = pycolmap.estimate_calibrated_two_view_geometry(camera, p1 + 0.5, camera, p2 + 0.5, matches, options)
    inliers = np.zeros(len(p1), bool)
    inliers[np.asarray(geometry.inlier_matches, int).reshape(-1, 2)[:, 0]] = True
    config = pycolmap.TwoViewGeometryConfiguration(geometry.config).name
    if config in ("UNDEFINED", "DEGENERATE") or inliers.sum() < MIN_MATCHES:
        return _failed(len(p1), f"pycolmap: {config}")
    rigid = geometry.cam2_from_cam1
    T_c2_c1 = np.eye(4)
    T_c2_c1[:3, :4] = rigid.matrix()
    T = np.linalg.inv(T_c2_c1)
    norm = np.linalg.norm(T[:3, 3])
    T[:3, 3] /= max(norm, 1e-12)
    return RelativePose(
        T, "homography" if "PLANAR" in config else "essential", inliers, rotation_only=config == "PANORAMIC"
    )


def _opencv_reason(error: cv2.error) -> str:
    """Why OpenCV failed, on one line: its own words without the source file and line it names."""
    words = " ".join(line.lstrip("> ").strip() for line in str(getattr(error, "err", "") or "").splitlines())
    return f"OpenCV could not fit a model to the pairs ({words or 'it gave no reason'})"


def _failed(count: int, reason: str) -> RelativePose:
    return RelativePose(np.eye(4), "failed", np.zeros(count, bool), reason=reason)


def estimate(
    p1: np.ndarray,
    p2: np.ndarray,
    K: np.ndarray,
    method: str = "auto",
    size: tuple[int, int] = (120, 160),
    previous_t: np.ndarray | None = None,
    sigma: float = 1.0,
    previous_normal: np.ndarray | None = None,
    ambiguous_takes_essential: bool = False,
) -> RelativePose:
    """Relative pose of camera 2 in camera 1 from matched pixels.

    Degenerate cases never raise, they give model "failed" with a ``reason``: a singular K, non-finite
    points, fewer than ``MIN_MATCHES`` distinct matches, collinear points (``MIN_SPREAD_PX``), a model
    that explains less than ``MIN_INLIER_RATIO`` of the matches or fewer than ``MIN_INLIERS`` of them, or, with
    "auto", pairs that a homography and an essential matrix explain alike with motions ``AMBIGUOUS_DEG`` apart
    where ``previous_t`` does not tell which (``_unambiguous``: the scene may not be a plane; with
    ``ambiguous_takes_essential`` and no ``previous_t``, the essential matrix's pose). A median flow below
    ``STATIC_FLOW_PX`` gives "static" (identity); pure rotation is flagged ``rotation_only`` (no translation).

    Args:
        p1, p2: (N, 2) pixels of the same points in cameras 1 and 2.
        K: (3, 3) camera matrix of both images.
        method: "auto" (ORB-SLAM's scores choose a homography or an essential matrix), "homography",
            "essential" or "pycolmap".
        size: (H, W) of the images.
        previous_t, previous_normal: the motion and the plane's normal (3,) measured before, in camera 1;
            they choose between a homography's decompositions (``homography_pose``).
        sigma: the pixel noise the model scores assume.
        ambiguous_takes_essential: where "auto" finds the pairs ambiguous and there is no ``previous_t``, take the
            essential matrix's pose (a homography's decomposition off a plane is often reversed) instead of failing.

    Returns:
        ``RelativePose``: ``T_c1_c2`` (4, 4) with a unit (or zero) translation, the model, the inliers (N,).

    Example:
        >>> import numpy as np
        >>> K = np.array([[100.0, 0, 80], [0, 100.0, 60], [0, 0, 1]])
        >>> X = np.random.default_rng(0).uniform([-1, -1, 3], [1, 1, 6], (60, 3))  # points at 3-6 m
        >>> p1 = X[:, :2] / X[:, 2:] * 100 + [80, 60]
        >>> X2 = X - [0.2, 0, 0]  # camera 2 is 0.2 m to the right
        >>> p2 = X2[:, :2] / X2[:, 2:] * 100 + [80, 60]
        >>> pose = estimate(p1, p2, K, "essential")
        >>> pose.model, bool(np.allclose(pose.T_c1_c2[:3, 3], [1, 0, 0], atol=0.01))
        ('essential', True)
    """
    if method not in METHODS:
        raise InputError(f"unknown relative pose method {method!r}; expected one of {', '.join(METHODS)}")
    p1, p2 = np.asarray(p1, np.float64).reshape(-1, 2), np.asarray(p2, np.float64).reshape(-1, 2)
    if len(p1) != len(p2):
        raise InputError(f"p1 and p2 must have the same length, got {len(p1)} and {len(p2)}")
    problem = _degenerate(p1, p2, K)
    if problem:
        return _failed(len(p1), problem)
    if np.median(np.linalg.norm(p2 - p1, axis=1)) < STATIC_FLOW_PX:
        return RelativePose(np.eye(4), "static", np.ones(len(p1), bool), reason="no motion")
    try:
        pose = _estimate(p1, p2, K, method, size, previous_t, sigma, previous_normal, ambiguous_takes_essential)
    except cv2.error as error:  # USAC asserts on some degenerate samples instead of failing softly
        return _failed(len(p1), _opencv_reason(error))
    if pose.ok and pose.inlier_ratio < MIN_INLIER_RATIO:
        return _failed(len(p1), f"the {pose.model} explains {pose.inlier_ratio:.0%} of the matches, "
                                f"below {MIN_INLIER_RATIO:.0%}")  # fmt: skip
    if pose.ok and pose.model != "static" and pose.inliers.sum() < MIN_INLIERS:
        return _failed(len(p1), f"the {pose.model} explains {pose.inliers.sum()} pairs, fewer than {MIN_INLIERS}")
    return pose


def _degenerate(p1: np.ndarray, p2: np.ndarray, K: np.ndarray) -> str:
    """Why no relative pose can come from these matches and K ("" if one can)."""
    K = np.asarray(K, np.float64)
    if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0 or abs(np.linalg.det(K)) < 1e-12:
        return "the camera matrix K is singular or not finite"
    if not (np.all(np.isfinite(p1)) and np.all(np.isfinite(p2))):
        return "the matches hold non-finite coordinates"
    distinct = min(len(np.unique(np.round(p, 3).view(np.complex128))) for p in (p1, p2))  # rows as x + iy: fast
    if distinct < MIN_MATCHES:
        return f"{distinct} distinct matched points, at least {MIN_MATCHES} needed"
    for points in (p1, p2):
        spread = np.linalg.svd(points - points.mean(0), compute_uv=False) / np.sqrt(len(points))
        if spread[1] < MIN_SPREAD_PX:
            return "the matched points are (nearly) collinear"
    return ""


def _estimate(p1, p2, K, method, size, previous_t, sigma, previous_normal, ambiguous_takes_essential) -> RelativePose:
    if method == "pycolmap":
        return pycolmap_pose(p1, p2, K, size)
    if method == "homography":
        return homography_pose(p1, p2, K, previous_t=previous_t, previous_normal=previous_normal)
    if method == "essential":
        return essential_pose(p1, p2, K)
    model, H, inliers_h = select_model(p1, p2, sigma)
    if H is None:  # select_model's MAGSAC fit failed; homography_pose would repeat it
        planar = _failed(len(p1), "homography estimation failed")
    else:
        planar = homography_pose(p1, p2, K, H, previous_t, inliers_h, previous_normal)
    general = None
    if model == "essential":
        general = essential_pose(p1, p2, K)
        if general.ok and general.inliers.sum() >= planar.inliers.sum() + ESSENTIAL_MARGIN * len(p1):
            return general
    if not planar.ok:  # no pose from the plane: the essential matrix's
        return general if general is not None else essential_pose(p1, p2, K)
    if planar.rotation_only:
        return planar
    if general is None:  # the scores chose H: E only to check it
        general = essential_pose(p1, p2, K, fits=QUICK_FITS)
    off_plane = _transfer_px(H, p1, p2) > OFF_PLANE_PX
    if _contradicted(planar, general, off_plane, p1, p2, K):
        return general
    return _unambiguous(planar, general, previous_t, previous_normal, ambiguous_takes_essential)


def _unambiguous(
    planar: RelativePose,
    general: RelativePose,
    previous_t: np.ndarray | None,
    previous_normal: np.ndarray | None,
    takes_essential: bool = False,
) -> RelativePose:
    """The homography's pose ``planar`` unless it and the essential matrix's ``general`` move the camera
    ``AMBIGUOUS_DEG`` apart while E explains as many pairs (within ``AMBIGUOUS_SHARE`` of them) and the plane is
    not the one seen before (``previous_normal``, within ``SAME_PLANE_DEG``): then nothing shows the scene is a
    plane (off a plane a homography still fits pairs of little parallax, its decomposition degrees off and its
    translation often reversed) and the motion so far, ``previous_t`` (3,), decides: the
    homography's pose if it is within ``AMBIGUOUS_DEG`` of it, else E's if that one is; else a failed pose that
    says the pairs cannot tell (E's pose where ``takes_essential`` and there is no ``previous_t``)."""
    if not general.ok or general.rotation_only or planar.inlier_ratio < MIN_INLIER_RATIO:
        return planar  # (too little support fails the homography anyway, with that reason)
    apart = float(np.degrees(vector_angle(planar.T_c1_c2[:3, 3], general.T_c1_c2[:3, 3])))
    if apart <= AMBIGUOUS_DEG or general.inliers.sum() < planar.inliers.sum() - AMBIGUOUS_SHARE * len(planar.inliers):
        return planar
    if previous_normal is not None and np.degrees(vector_angle(planar.plane_normal, previous_normal)) <= SAME_PLANE_DEG:
        return planar  # a plane that lasts from frame to frame
    if previous_t is not None and np.linalg.norm(previous_t) > 0:
        for pose in (planar, general):  # the plane first: where both go along, a homography fits for a reason
            if np.degrees(vector_angle(pose.T_c1_c2[:3, 3], previous_t)) <= AMBIGUOUS_DEG:
                return pose
    elif takes_essential:
        return general
    return _failed(
        len(planar.inliers),
        f"ambiguous: the homography's and the essential matrix's translations are {apart:.0f} deg apart and "
        "both explain the pairs",
    )


def _contradicted(
    planar: RelativePose, general: RelativePose, off_plane: np.ndarray, p1: np.ndarray, p2: np.ndarray, K: np.ndarray
) -> bool:
    """Whether the pairs p1 -> p2 (N, 2) off the homography's plane (``off_plane`` (N,): over ``OFF_PLANE_PX``
    from where it takes them) contradict the pose decomposed from it, ``planar``, in favour of the essential
    matrix's, ``general``: ``OFF_PLANE_MARGIN`` of E's inliers are off the plane and the pairs' epipolar
    residual is ``EPIPOLAR_GAIN`` times smaller under E's pose. A room's other walls, seen over a short
    baseline, still fit the dominant wall's homography within its tolerance, and that homography's pose can
    then be degrees off."""
    if not general.ok or general.rotation_only or np.sum(general.inliers & off_plane) < OFF_PLANE_MARGIN:
        return False
    return _epipolar_residual(planar, p1, p2, K) > EPIPOLAR_GAIN * _epipolar_residual(general, p1, p2, K)


def _fundamental(p1: np.ndarray, p2: np.ndarray) -> np.ndarray | None:
    """The fundamental matrix (3, 3) of the pairs by MAGSAC, or by RANSAC where OpenCV's USAC asserts on a sample
    (it does on some: "!model.empty()"); None (or stacked solutions) where OpenCV finds none."""
    try:
        return cv2.findFundamentalMat(p1, p2, cv2.USAC_MAGSAC, 1.0, 0.999)[0]
    except cv2.error:
        return cv2.findFundamentalMat(p1, p2, cv2.FM_RANSAC, 1.0, 0.999)[0]


def select_model(p1: np.ndarray, p2: np.ndarray, sigma: float = 1.0) -> tuple[str, np.ndarray | None, np.ndarray]:
    """ORB-SLAM's choice between a homography and a fundamental matrix: "homography" when
    R_H = S_H / (S_H + S_F) > ``HOMOGRAPHY_RATIO``. Returns (model, H or None, H inlier mask (N,)).

    Between frames with little parallax both models fit and R_H does not discriminate, and a plane seen
    over a short baseline makes E nearly degenerate: "auto" therefore keeps E only when its pose explains
    ``ESSENTIAL_MARGIN`` more of the pairs than the homography does, or (``_estimate``) when
    ``OFF_PLANE_MARGIN`` of its inliers lie ``OFF_PLANE_PX`` off the homography and the pairs' epipolar
    residual under its pose is ``EPIPOLAR_GAIN`` times smaller than under the homography's."""
    H, _ = cv2.findHomography(p1, p2, cv2.USAC_MAGSAC, 1.5, maxIters=2000, confidence=0.999)
    if H is None:
        return "essential", None, np.zeros(len(p1), bool)
    F = _fundamental(p1, p2)
    score_h, inliers_h = _score_homography(H, p1, p2, sigma)
    score_f = _score_fundamental(F[:3], p1, p2, sigma)[0] if F is not None and F.shape[0] >= 3 else 0.0
    ratio = score_h / max(score_h + score_f, 1e-12)
    return ("homography" if ratio > HOMOGRAPHY_RATIO else "essential"), H, inliers_h
