"""A local map for monocular odometry: landmarks triangulated from keyframes, each frame located in it by PnP,
a bundle adjustment over a window of keyframes, culling so that long runs stay flat.

Landmarks are keyed by the front-end's track ids: a track is one physical point for as long as the front-end
follows it, so its observations in the keyframes are the landmark's. The map is built in the world frame of
the odometry's first keyframe; its scale is that of the first baseline it was triangulated from (the caller
chooses it: a true length where the input has one, else 1), and the map carries it from keyframe to keyframe.

Bundle adjustment is gtsam's Levenberg-Marquardt over ``GenericProjectionFactorCal3_S2`` factors (or pycolmap's Ceres on
the same problem, ``MapConfig.adjuster``, for every window but the first map's, whose marginals gtsam measures) with a
Huber loss: the window's keyframe poses and the landmarks two of them observe; the window's oldest keyframe is held
fixed and its distance to the next one kept (gtsam: a ``RangeFactorPose3``; pycolmap: the held keyframes that left the
window, or where none has yet, its solution scaled back to that distance): gauge and scale. The last ``fixed_keyframes``
keyframes to leave the window stay in it, held where they are, with their observations of its landmarks: the landmarks
keep the wider baselines older views gave them (without, a window of keyframes a few pixels apart let their depths and
its scale wander). The map's first two keyframes are adjusted as soon as it starts, which it does only once their
marginal covariance determines the direction between them. Observations behind a camera or farther than
``max_reprojection_px`` from their landmark's projection afterwards are dropped, as are landmarks left with fewer than
two; landmarks that no keyframe of the window observes are dropped with the keyframes that leave it. With
``adjust_frames``, each frame located between keyframes joins the adjustment as it comes (``observe``), with the frames
located since the keyframe before the current one: its observations refine the landmarks the next frame is located
against, and its own pose is the adjusted one. Frames make no landmarks."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, replace

import cv2
import gtsam
import numpy as np

from deepslam.backend.config import MapConfig
from deepslam.geometry import vector_angle
from deepslam.interrupts import import_pycolmap

PNP_ITERATIONS = 200  # PnP RANSAC's iterations
FIXED_SIGMA = 1e-6  # rad and m: the prior that holds the window's oldest keyframe (a hard constraint would need QR)
INITIAL_VIEWS = 20  # a frame measured two-view while a map waits is adjusted with at most this many views ...
INITIAL_TRIANGULATION_PX = 1.0  # ... and the landmarks of rays this far apart (radians x focal length), ...
INITIAL_ITERATIONS = 100  # ... until Levenberg-Marquardt converges (10-90 iterations), at most this many
START_GAIN = 2.0  # another start of those views is taken where it fits them this many times better (``_fit_error``)
KEPT_FRAMES = 50  # the frames a map waits through kept to be located in it once it starts (``InitialViews.keep``)


@dataclass
class Keyframe:
    """A keyframe of the map: its index in processing order, ``T_world_cam`` (4, 4), K (3, 3), and the track
    ids (N,) and pixels (N, 2) it observed."""

    index: int
    T_world_cam: np.ndarray
    K: np.ndarray
    ids: np.ndarray
    points: np.ndarray

    def projection(self) -> np.ndarray:
        """The 3x4 projection matrix K [R | t] of world points into this keyframe."""
        T_cam_world = np.linalg.inv(self.T_world_cam)
        return self.K @ T_cam_world[:3]


@dataclass
class Location:
    """A frame located in the map: ``T_world_cam`` (4, 4) or None where PnP found no pose, the landmark
    ids (M,) it was given and which of them are inliers (M,) bool, and why it failed."""

    T_world_cam: np.ndarray | None
    ids: np.ndarray
    inliers: np.ndarray
    reason: str = ""


def project(T_world_cam: np.ndarray, K: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World points (N, 3) seen by the camera ``T_world_cam`` (4, 4) with K (3, 3): pixels (N, 2) and depths (N,)."""
    T_cam_world = np.linalg.inv(T_world_cam)
    camera = points @ T_cam_world[:3, :3].T + T_cam_world[:3, 3]
    pixels = camera @ K.T
    depth = camera[:, 2]
    return pixels[:, :2] / np.where(np.abs(depth) > 1e-12, depth, 1e-12)[:, None], depth


def _levenberg_marquardt(iterations: int, converge: bool) -> gtsam.LevenbergMarquardtParams:
    """gtsam's Levenberg-Marquardt for at most ``iterations``, damped by lambda times the identity (lambda at most
    1e5: from a view tens of degrees off it often takes no step at all, lambda reaching its bound first); with
    ``converge`` for up to ``INITIAL_ITERATIONS``, damped by the diagonal of its Hessian (Marquardt's scaling, as
    Ceres damps) with no practical bound on lambda."""
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(INITIAL_ITERATIONS if converge else iterations)
    if converge:
        params.setDiagonalDamping(True)
        params.setlambdaUpperBound(1e12)
    return params


def calibration(K: np.ndarray) -> gtsam.Cal3_S2:
    """gtsam's pinhole calibration of K (3, 3)."""
    return gtsam.Cal3_S2(K[0, 0], K[1, 1], K[0, 1], K[0, 2], K[1, 2])


def pixel_noise(huber_px: float) -> gtsam.noiseModel.Base:
    """The noise of a projection factor: 1 px a coordinate, Huber-robust from ``huber_px``."""
    return gtsam.noiseModel.Robust.Create(
        gtsam.noiseModel.mEstimator.Huber.Create(huber_px), gtsam.noiseModel.Isotropic.Sigma(2, 1.0)
    )


def _pose_from_pnp(rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    T_cam_world = np.eye(4)
    T_cam_world[:3, :3] = cv2.Rodrigues(rvec)[0]
    T_cam_world[:3, 3] = tvec.ravel()
    return np.linalg.inv(T_cam_world)


def _pnp_guess(T_world_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    T_cam_world = np.linalg.inv(T_world_cam)
    return cv2.Rodrigues(T_cam_world[:3, :3])[0], T_cam_world[:3, 3].reshape(3, 1).copy()


class LocalMap:
    """Landmarks (track id -> world point) and the window of keyframes that observe them.

    Example:
        >>> import numpy as np
        >>> from deepslam.backend.config import MapConfig
        >>> K = np.array([[100.0, 0, 80], [0, 100.0, 60], [0, 0, 1]])
        >>> rng = np.random.default_rng(0)
        >>> world = np.c_[rng.uniform(-1, 1, (60, 2)), rng.uniform(2, 4, 60)]
        >>> first, second = np.eye(4), np.eye(4); second[0, 3] = 0.5
        >>> views = [Keyframe(i, T, K, np.arange(60), project(T, K, world)[0]) for i, T in enumerate((first, second))]
        >>> local_map = LocalMap(MapConfig())
        >>> local_map.start(*views)
        60
        >>> moved = np.eye(4); moved[0, 3] = 0.7
        >>> location = local_map.locate(np.arange(60), project(moved, K, world)[0], K, second)
        >>> np.round(location.T_world_cam[:3, 3], 3).tolist() == [0.7, 0.0, 0.0], int(location.inliers.sum())
        (True, 60)
    """

    def __init__(self, config: MapConfig | None = None):
        self.config = config or MapConfig()
        self.landmarks: dict[int, np.ndarray] = {}  # track id -> world point (3,)
        self.keyframes: list[Keyframe] = []  # the window, oldest first
        self.retired: list[Keyframe] = []  # keyframes that left the window, held fixed in its adjustment
        self.frames: list[Keyframe] = []  # frames located since the window's last keyframe but one (``observe``)

    @property
    def started(self) -> bool:
        return bool(self.landmarks)

    def holds(self, index: int) -> bool:
        """Whether the map has started and frame ``index`` is a keyframe of its window."""
        return self.started and any(keyframe.index == index for keyframe in self.keyframes)

    def pose(self, index: int) -> np.ndarray:
        """The pose ``T_world_cam`` (4, 4) of the window's keyframe ``index``."""
        return next(keyframe.T_world_cam for keyframe in self.keyframes if keyframe.index == index)

    def baseline_px(self, location: Location, K: np.ndarray, index: int) -> float:
        """The angle (px: radians x focal length, K (3, 3)) keyframe ``index``'s centre and the centre of a frame
        located at ``location`` (with a pose) span at the median depth of the landmarks it was given."""
        depth = np.median(project(location.T_world_cam, K, self.points_of(location.ids))[1])
        length = np.linalg.norm((np.linalg.inv(self.pose(index)) @ location.T_world_cam)[:3, 3])
        return float(length / max(depth, 1e-9) * K[0, 0])

    def points(self) -> tuple[np.ndarray, np.ndarray]:
        """Landmark ids (M,) and world points (M, 3)."""
        ids = np.fromiter(self.landmarks, np.int64, len(self.landmarks))
        return ids, np.array([self.landmarks[i] for i in ids]).reshape(-1, 3)

    def known(self, ids: np.ndarray) -> np.ndarray:
        """Which of the track ``ids`` (N,) are landmarks (N,) bool."""
        return np.fromiter((int(i) in self.landmarks for i in ids), bool, len(ids))

    def points_of(self, ids: np.ndarray) -> np.ndarray:
        """The world points (N, 3) of the landmarks ``ids`` (N,)."""
        return np.array([self.landmarks[int(i)] for i in ids]).reshape(-1, 3)

    def start(self, first: Keyframe, second: Keyframe) -> int:
        """Triangulate the tracks two keyframes share (their poses already at the map's scale); the map starts
        if ``min_initial_landmarks`` were seen from ``min_initial_px`` apart and, after the two are adjusted, the
        direction between them is known to ``max_start_deg`` (``_direction_sigma_deg``: a short or noisy
        baseline fits its points just as well turned tens of degrees, and a map started there is off for good).
        Returns how many (0 when it did not start)."""
        self.landmarks, self.keyframes, self.retired, self.frames = {}, [first], [], []
        made = self._triangulate(second, self.config.min_initial_px)
        if made < self.config.min_initial_landmarks:
            self.landmarks, self.keyframes = {}, []
            return 0
        self.keyframes.append(second)
        adjusted = self.adjust()
        if adjusted is None or _direction_sigma_deg(*adjusted, first, second) > self.config.max_start_deg:
            self.landmarks, self.keyframes = {}, []
            return 0
        return made

    def locate(self, ids: np.ndarray, points: np.ndarray, K: np.ndarray, guess: np.ndarray) -> Location:
        """The pose of a frame whose tracks ``ids`` (N,) were seen at ``points`` (N, 2): PnP with RANSAC on those
        that are landmarks, refined by Levenberg-Marquardt on its inliers (motion only); ``guess`` (4, 4): the
        pose expected. The returned ids are the tracks that are landmarks."""
        known = self.known(ids)
        ids, points = ids[known], np.asarray(points, np.float64)[known]
        if len(ids) < self.config.min_located:
            return Location(None, ids, np.zeros(len(ids), bool), f"{len(ids)} landmarks in view")
        world = self.points_of(ids)
        rvec, tvec = _pnp_guess(guess)
        found, rvec, tvec, chosen = cv2.solvePnPRansac(
            world, points, K, None, rvec, tvec, useExtrinsicGuess=True, iterationsCount=PNP_ITERATIONS,
            reprojectionError=self.config.pnp_px, confidence=0.999, flags=cv2.SOLVEPNP_ITERATIVE,
        )  # fmt: skip
        if not found or chosen is None or len(chosen) < self.config.min_located:
            return Location(None, ids, np.zeros(len(ids), bool), "PnP found no pose")
        inliers = np.zeros(len(ids), bool)
        inliers[chosen.ravel()] = True
        for _ in range(2):  # refine on the inliers, then take the inliers of the refined pose
            rvec, tvec = cv2.solvePnPRefineLM(world[inliers], points[inliers], K, None, rvec, tvec)
            pose = _pose_from_pnp(rvec, tvec)
            pixels, depth = project(pose, K, world)
            inliers = (np.linalg.norm(pixels - points, axis=1) < self.config.pnp_px) & (depth > 0)
            if inliers.sum() < self.config.min_located:
                return Location(None, ids, inliers, f"{int(inliers.sum())} landmarks agree with PnP's pose")
        return Location(pose, ids, inliers)

    def observe(self, frame: Keyframe) -> np.ndarray:
        """A frame located in the map between keyframes (its pose from ``locate``, its inlier tracks' ids and
        pixels) joins the bundle adjustment; returns its pose ``T_world_cam`` (4, 4) after it."""
        self.frames.append(frame)
        self._adjust_window()
        return frame.T_world_cam

    def _views(self) -> list[Keyframe]:
        """What the bundle adjustment moves: the window's keyframes, then the frames it observed."""
        return self.keyframes + self.frames

    def add(self, keyframe: Keyframe) -> int:
        """A new keyframe (its pose from ``locate``): new landmarks from the tracks it shares with the window,
        a local bundle adjustment, culling. Returns how many landmarks were made."""
        made = self._triangulate(keyframe)
        window = self.keyframes + [keyframe]
        self.keyframes, left = window[-self.config.window :], window[: -self.config.window]
        retired = self.retired + left
        self.retired = retired[max(0, len(retired) - self.config.fixed_keyframes) :]
        self.frames = [frame for frame in self.frames if frame.index > self.keyframes[-2].index]
        self._adjust_window()
        self._cull()
        return made

    def _triangulate(self, keyframe: Keyframe, min_px: float | None = None) -> int:
        """Landmarks for the tracks of ``keyframe`` that are none yet, each from the oldest keyframe of the window
        that saw it (the widest baseline), kept where in front of both cameras, reprojecting within
        ``max_reprojection_px`` and seen from ``min_px`` apart (an angle in pixels of the new keyframe's focal
        length; default ``min_triangulation_px``)."""
        made, min_px = 0, self.config.min_triangulation_px if min_px is None else min_px
        for older in self.keyframes:
            new = ~self.known(keyframe.ids)
            _, a, b = np.intersect1d(older.ids, keyframe.ids[new], return_indices=True)
            if len(a) == 0:
                continue
            b = np.nonzero(new)[0][b]
            homogeneous = cv2.triangulatePoints(
                older.projection(), keyframe.projection(), older.points[a].T, keyframe.points[b].T
            )
            with np.errstate(divide="ignore", invalid="ignore"):
                world = (homogeneous[:3] / homogeneous[3]).T
            good = np.all(np.isfinite(world), axis=1) & self._well_seen(world, (older, a), (keyframe, b))
            rays = [world - view.T_world_cam[:3, 3] for view in (older, keyframe)]
            good &= vector_angle(*rays) * keyframe.K[0, 0] >= min_px  # radians x focal length: pixels
            for track, point in zip(keyframe.ids[b[good]], world[good], strict=True):
                self.landmarks[int(track)] = point
            made += int(good.sum())
        return made

    def _well_seen(self, world: np.ndarray, *views: tuple[Keyframe, np.ndarray]) -> np.ndarray:
        """Which world points (N, 3) lie in front of each view and project within ``max_reprojection_px`` of
        its observations (each view: a keyframe and the indices (N,) of its points)."""
        good = np.ones(len(world), bool)
        for keyframe, index in views:
            pixels, depth = project(keyframe.T_world_cam, keyframe.K, np.nan_to_num(world))
            good &= (depth > 0) & (
                np.linalg.norm(pixels - keyframe.points[index], axis=1) < self.config.max_reprojection_px
            )
        return good

    def _adjust_window(self) -> None:
        """The window's bundle adjustment as ``adjust`` makes it, by pycolmap where ``config.adjuster`` says so
        (``adjust_with_pycolmap``)."""
        if self.config.adjuster == "gtsam" or len(self.keyframes) < 2:
            self.adjust()
            return
        adjusted = self.adjusted_landmarks()
        if len(adjusted):
            adjust_with_pycolmap(self._views(), self.retired, self.landmarks, adjusted, self.config)
            self._drop_outliers()

    def adjust(self, ranged: int = 1, converge: bool = False) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values] | None:
        """Bundle adjustment of the window and the frames it observed (the oldest keyframe fixed, the distance to
        it of the keyframe at window position ``ranged`` kept: by default the next) over the landmarks two or more
        of them observe, then drop observations that do not fit (``_drop_outliers``). Levenberg-Marquardt takes
        ``config.iterations``, or with ``converge`` runs until it converges (``_levenberg_marquardt``). Returns the
        graph and its solution (None where there was nothing to adjust)."""
        cameras, adjusted = self._views(), self.adjusted_landmarks()
        if len(self.keyframes) < 2 or not len(adjusted):
            return None
        graph, values, noise = gtsam.NonlinearFactorGraph(), gtsam.Values(), pixel_noise(self.config.huber_px)
        for position, keyframe in enumerate(cameras):
            values.insert(gtsam.symbol("x", position), gtsam.Pose3(keyframe.T_world_cam))
        for track in adjusted.tolist():
            values.insert(gtsam.symbol("l", track), gtsam.Point3(self.landmarks[track]))
        self._hold_gauge(graph, values, ranged)
        for position, keyframe in enumerate(cameras):
            pose, camera = gtsam.symbol("x", position), calibration(keyframe.K)
            for landmark, pixel in _observations(keyframe, adjusted):
                graph.add(gtsam.GenericProjectionFactorCal3_S2(pixel, noise, pose, landmark, camera, False, False))
        self._hold_retired(graph, adjusted, noise)
        params = _levenberg_marquardt(self.config.iterations, converge)
        result = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
        for position, keyframe in enumerate(cameras):
            keyframe.T_world_cam = result.atPose3(gtsam.symbol("x", position)).matrix()
        for track in adjusted.tolist():
            self.landmarks[track] = result.atPoint3(gtsam.symbol("l", track))
        self._drop_outliers()
        return graph, result

    def adjusted_landmarks(self) -> np.ndarray:
        """The landmark ids (M,) the next bundle adjustment moves: those two or more of its views (the window's
        keyframes and the frames it observed) observe, ascending."""
        observed = np.concatenate([view.ids[self.known(view.ids)] for view in self._views()])
        tracks, views = np.unique(observed.astype(np.int64), return_counts=True)
        return tracks[views >= 2]

    def _hold_gauge(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, ranged: int) -> None:
        """Hold the window's oldest keyframe (variable ``x0`` in ``values``) where it is and keep its distance to
        the keyframe at window position ``ranged``: the gauge and the scale of the adjustment."""
        first, second = (gtsam.symbol("x", position) for position in (0, ranged))
        graph.add(
            gtsam.PriorFactorPose3(first, values.atPose3(first), gtsam.noiseModel.Isotropic.Sigma(6, FIXED_SIGMA))
        )
        distance = np.linalg.norm(self.keyframes[ranged].T_world_cam[:3, 3] - self.keyframes[0].T_world_cam[:3, 3])
        kept = gtsam.noiseModel.Isotropic.Sigma(1, 1e-4 * distance + 1e-9)
        graph.add(gtsam.RangeFactorPose3(first, second, float(distance), kept))

    def _hold_retired(
        self, graph: gtsam.NonlinearFactorGraph, adjusted: np.ndarray, noise: gtsam.noiseModel.Base
    ) -> None:
        """Add the observations (with ``noise``) of the ``adjusted`` landmarks (ids (M,)) by the keyframes that left
        the window to ``graph``, from cameras held where they are (constants, not variables)."""
        for keyframe in self.retired:
            camera = gtsam.PinholeCameraCal3_S2(gtsam.Pose3(keyframe.T_world_cam), calibration(keyframe.K))
            for landmark, pixel in _observations(keyframe, adjusted):
                graph.add(gtsam.TriangulationFactorCal3_S2(camera, pixel, noise, landmark))

    def _drop_outliers(self) -> None:
        """Drop the adjusted views' observations behind the camera or farther than ``max_reprojection_px`` from
        their landmark's projection."""
        for keyframe in self._views():
            known = self.known(keyframe.ids)
            world = self.points_of(keyframe.ids[known])
            pixels, depth = project(keyframe.T_world_cam, keyframe.K, world)
            bad = (depth <= 0) | (
                np.linalg.norm(pixels - keyframe.points[known], axis=1) > self.config.max_reprojection_px
            )
            keep = np.ones(len(keyframe.ids), bool)
            keep[np.nonzero(known)[0][bad]] = False
            keyframe.ids, keyframe.points = keyframe.ids[keep], keyframe.points[keep]

    def _cull(self) -> None:
        """Drop the landmarks no keyframe of the window observes."""
        observed = set(np.concatenate([k.ids for k in self.keyframes]).tolist())
        self.landmarks = {track: point for track, point in self.landmarks.items() if track in observed}


def adjust_with_pycolmap(
    moving: list[Keyframe],
    held: list[Keyframe],
    landmarks: dict[int, np.ndarray],
    adjusted: np.ndarray,
    config: MapConfig,
) -> None:
    """pycolmap's (Ceres') bundle adjustment of the ``moving`` views' poses (in place; the first one held) and the
    ``adjusted`` landmarks (ids (M,), in ``landmarks`` in place), with the observations of the ``held`` views as well
    (constant poses): ``LocalMap.adjust``'s problem, with its Huber loss and iteration cap, one thread. The first
    view holds the gauge; the held views hold the scale with it, or where there are none, the second view's
    distance from the first is kept (``_keep_distance``), as ``LocalMap.adjust`` keeps it."""
    pycolmap = import_pycolmap()

    reconstruction, problem, points = _pycolmap_problem(moving + held, len(moving), landmarks, adjusted)
    options = pycolmap.BundleAdjustmentOptions(refine_focal_length=False, refine_extra_params=False)
    options.print_summary = False
    options.ceres.loss_function_type = pycolmap.LossFunctionType.HUBER
    options.ceres.loss_function_scale = config.huber_px
    options.ceres.solver_options.max_num_iterations = config.iterations
    options.ceres.solver_options.num_threads = 1
    distance = np.linalg.norm(moving[1].T_world_cam[:3, 3] - moving[0].T_world_cam[:3, 3])
    warnings_shown, pycolmap.logging.minloglevel = pycolmap.logging.minloglevel, int(pycolmap.logging.Level.ERROR)
    try:  # Ceres warns when a step's factorisation fails, then damps the step more, as gtsam does silently
        pycolmap.create_default_bundle_adjuster(options, problem, reconstruction).solve()
    finally:
        pycolmap.logging.minloglevel = warnings_shown
    for image_id, view in enumerate(moving, start=1):
        T_cam_world = np.eye(4)
        T_cam_world[:3] = reconstruction.image(image_id).cam_from_world().matrix()
        view.T_world_cam = np.linalg.inv(T_cam_world)
    for track, point in points.items():
        landmarks[track] = np.array(reconstruction.point3D(point).xyz)
    if not held:
        _keep_distance(moving, landmarks, points, distance)


def _keep_distance(
    views: list[Keyframe], landmarks: dict[int, np.ndarray], moved: Iterable[int], distance: float
) -> None:
    """Scale ``views`` (their positions, in place) and the ``moved`` landmarks (ids, in ``landmarks`` in place) about
    the first view's position so that the second lies ``distance`` from it again: a solution of a bundle adjustment
    with only the first view held is one up to scale, and every such scaling fits the observations alike."""
    origin = views[0].T_world_cam[:3, 3].copy()
    scale = distance / max(float(np.linalg.norm(views[1].T_world_cam[:3, 3] - origin)), 1e-12)
    for view in views[1:]:
        view.T_world_cam[:3, 3] = origin + scale * (view.T_world_cam[:3, 3] - origin)
    for track in moved:
        landmarks[track] = origin + scale * (landmarks[track] - origin)


def _pycolmap_problem(views: list[Keyframe], moving: int, landmarks: dict[int, np.ndarray], adjusted: np.ndarray):
    """pycolmap's reconstruction of ``views`` (image ids from 1; the first ``moving`` of them move but the first, the
    rest are held constant) observing the ``adjusted`` landmarks, its adjustment config, and each landmark's point
    id."""
    pycolmap = import_pycolmap()

    K = views[0].K
    reconstruction, problem, seen, points = pycolmap.Reconstruction(), pycolmap.BundleAdjustmentConfig(), {}, {}
    size = (round(2 * K[0, 2] + 1), round(2 * K[1, 2] + 1))  # a size only names the camera: the solver needs none
    camera = pycolmap.Camera(model="PINHOLE", width=size[0], height=size[1], camera_id=1)
    camera.params = K[[0, 1, 0, 1], [0, 1, 2, 2]]
    reconstruction.add_camera_with_trivial_rig(camera)
    for image_id, view in enumerate(views, start=1):
        observed = np.isin(view.ids, adjusted)
        T_cam_world = np.linalg.inv(view.T_world_cam)
        image = pycolmap.Image(name=str(image_id), keypoints=view.points[observed], camera_id=1, image_id=image_id)
        pose = pycolmap.Rigid3d(pycolmap.Rotation3d(T_cam_world[:3, :3]), T_cam_world[:3, 3])
        reconstruction.add_image_with_trivial_frame(image, pose)
        problem.add_image(image_id)
        for index, track in enumerate(view.ids[observed].tolist()):
            seen.setdefault(track, []).append((image_id, index))
    for image_id in (1, *range(moving + 1, len(views) + 1)):
        problem.set_constant_rig_from_world_pose(image_id)
    for track, observations in seen.items():
        elements = pycolmap.Track()
        for image_id, index in observations:
            elements.add_element(image_id, index)
        points[track] = reconstruction.add_point3D(landmarks[track], elements)
        problem.add_variable_point(points[track])
    problem.set_constant_cam_intrinsics(1)
    # where only the first view is held, one coordinate of the second's position holds the scale (no free direction)
    problem.fix_gauge(pycolmap.BundleAdjustmentGauge.TWO_CAMS_FROM_WORLD)
    return reconstruction, problem, points


def _observations(keyframe: Keyframe, adjusted: np.ndarray) -> Iterator[tuple[int, np.ndarray]]:
    """The gtsam landmark key and pixel (2,) of each of ``keyframe``'s observations of the ``adjusted`` landmarks
    (ids (M,)), in the keyframe's order."""
    observed = np.isin(keyframe.ids, adjusted)
    for track, pixel in zip(keyframe.ids[observed].tolist(), keyframe.points[observed], strict=True):
        yield gtsam.symbol("l", track), pixel


def adjust_views(
    views: list[Keyframe], config: MapConfig, min_px: float, starts: Iterable[np.ndarray] = ()
) -> np.ndarray | None:
    """The pose ``T_world_cam`` (4, 4) of the last of ``views`` after one bundle adjustment of them all (copies:
    the views stay as they are) with the landmarks their tracks triangulate from rays ``min_px`` apart (each from
    the first view that saw it): the first view held, the last one's distance from it kept (gauge and scale).
    ``starts``: other poses (4, 4) the last view may start from, at its distance from the first; the adjustment
    from the view's own pose is kept unless another fits ``START_GAIN`` times better (``_fit_error``; from a
    view measured degrees off, one can settle in a wrong minimum that another start avoids). None where they
    triangulate fewer than ``config.min_located`` landmarks."""
    last = views[-1]
    results = [
        _adjusted_last([*views[:-1], replace(last, T_world_cam=T)], config, min_px) for T in (last.T_world_cam, *starts)
    ]
    finished = [result for result in results if result is not None]
    if not finished:
        return None
    best = min(finished, key=lambda result: result[1])
    measured = results[0]
    return measured[0] if measured is not None and measured[1] <= START_GAIN * best[1] else best[0]


def _adjusted_last(views: list[Keyframe], config: MapConfig, min_px: float) -> tuple[np.ndarray, float] | None:
    """``adjust_views`` from the views as they are: the last one's pose (4, 4) and how well the adjustment fits their
    observations (``_fit_error``)."""
    trial = LocalMap(replace(config, window=len(views), fixed_keyframes=0))
    views = [replace(view) for view in views]
    trial.keyframes = views[:1]
    for view in views[1:]:
        trial._triangulate(view, min_px)
        trial.keyframes.append(view)
    adjusted = trial.adjusted_landmarks()
    observations = sum(int(np.isin(view.ids, adjusted).sum()) for view in views)
    solved = trial.adjust(len(views) - 1, converge=True) if len(trial.landmarks) >= config.min_located else None
    if solved is None:
        return None
    return views[-1].T_world_cam, _fit_error(trial, adjusted, observations)


def _fit_error(adjusted_map: LocalMap, adjusted: np.ndarray, observations: int) -> float:
    """How well a bundle adjustment of ``adjusted_map`` fits the ``observations`` its views made of the ``adjusted``
    landmarks (ids (M,)): Huber's loss of each kept one's distance (px) from its landmark's projection and, for each
    dropped as an outlier (behind its camera or farther than ``max_reprojection_px``: ``_drop_outliers``), the loss
    at ``max_reprojection_px``, over the observations: a truncated loss, by which a landmark an adjustment pushed
    behind its cameras costs as much as any other outlier (gtsam's error takes such a factor's residual as twice the
    focal length in each coordinate, with no gradient: hundreds of times an inlier's error)."""
    config = adjusted_map.config
    loss = gtsam.noiseModel.mEstimator.Huber.Create(config.huber_px)
    total, kept = 0.0, 0
    for view in adjusted_map.keyframes:
        seen = np.isin(view.ids, adjusted)
        pixels, _ = project(view.T_world_cam, view.K, adjusted_map.points_of(view.ids[seen]))
        total += sum(loss.loss(float(d)) for d in np.linalg.norm(pixels - view.points[seen], axis=1))
        kept += int(seen.sum())
    return (total + (observations - kept) * loss.loss(config.max_reprojection_px)) / max(observations, 1)


def _at_distance(T_world_cam: np.ndarray, origin: np.ndarray, distance: float) -> np.ndarray | None:
    """``T_world_cam`` (4, 4) moved along its direction from ``origin`` (4, 4) to ``distance`` from it; None where
    it stands at the origin."""
    offset = T_world_cam[:3, 3] - origin[:3, 3]
    length = float(np.linalg.norm(offset))
    if length < 1e-9:
        return None
    moved = T_world_cam.copy()
    moved[:3, 3] = origin[:3, 3] + offset * distance / length
    return moved


class InitialViews:
    """The frames a map waits through, until it starts.

    - The views: the frames since the keyframe the map waits to start from whose tracks moved ``min_parallax``
      px, adjusted together with each new one. Measured one by one from a keyframe a few pixels away, their
      translations point degrees apart (a homography here, an essential matrix there); together they agree.
    - The kept frames: every frame's tracks since a map last held the keyframe (the last ``KEPT_FRAMES``), to be
      located in the map once it starts (``locate_kept``); ``located`` holds where it placed them.

    Args:
        config: the map's settings (its bundle adjustment and ``min_located``).
    """

    def __init__(self, config: MapConfig):
        self.config = config
        self.views: dict[int, Keyframe] = {}  # the frames kept as views, by index, in order
        self.kept: dict[int, Keyframe] = {}  # the frames to locate once a map starts, by index, in order
        # index -> (the keyframe the map started from, the frame seen from it T_kf_frame (4, 4))
        self.located: dict[int, tuple[int, np.ndarray]] = {}

    def adjust(self, first: Keyframe, current: Keyframe, estimate: Callable[[int], np.ndarray]) -> np.ndarray | None:
        """The pose ``T_world_cam`` (4, 4) of ``current`` adjusted together with the keyframe ``first`` (held, with
        ``current``'s distance from it) and up to ``INITIAL_VIEWS`` of the views, each at its latest ``estimate``
        (``T_world_cam`` (4, 4) of a frame's index), started from its measured pose and also from the frame before's
        at the same distance (``adjust_views``' ``starts``); None where they triangulate too few landmarks."""
        earlier = [replace(view, T_world_cam=estimate(index)) for index, view in self.views.items()]
        distance = float(np.linalg.norm(current.T_world_cam[:3, 3] - first.T_world_cam[:3, 3]))
        before = _at_distance(estimate(current.index - 1), first.T_world_cam, distance)
        views = [first, *earlier[-INITIAL_VIEWS:], current]
        return adjust_views(views, self.config, INITIAL_TRIANGULATION_PX, [] if before is None else [before])

    def add(self, view: Keyframe) -> None:
        """Keep ``view`` (a frame's confirmed pairs with the keyframe) for the frames after it."""
        self.views[view.index] = view

    def keep_after(self, keyframe: int | None) -> None:
        """Keep only the views of frames after ``keyframe``; no views and no kept frames where it is None (no map
        waits)."""
        self.views = {} if keyframe is None else {i: view for i, view in self.views.items() if i > keyframe}
        if keyframe is None:
            self.kept = {}

    def keep(self, frame: Keyframe) -> None:
        """Keep ``frame`` (its tracks; its pose is not used) to locate it once a map starts: the last
        ``KEPT_FRAMES``."""
        self.kept[frame.index] = frame
        if len(self.kept) > KEPT_FRAMES:
            del self.kept[min(self.kept)]

    def locate_kept(self, local_map: LocalMap, keyframe: int, guess: Callable[[int], np.ndarray]) -> None:
        """A map has just started from ``keyframe``: the kept frames but that one, located in it (PnP on their
        tracks that are its landmarks, from ``guess``: a frame's index -> ``T_world_cam`` (4, 4) in the map's
        world), into ``located``; none kept after. Measured two-view over a few pixels of parallax, their online
        estimates point degrees off; the map's landmarks place them from depths the two views could not tell."""
        T_map_kf = local_map.pose(keyframe)
        for index, frame in self.kept.items():
            if index == keyframe:
                continue
            location = local_map.locate(frame.ids, frame.points, frame.K, guess(index))
            if location.T_world_cam is not None:
                self.located[index] = (keyframe, np.linalg.inv(T_map_kf) @ location.T_world_cam)
        self.kept = {}


def _direction_sigma_deg(
    graph: gtsam.NonlinearFactorGraph, result: gtsam.Values, first: Keyframe, second: Keyframe
) -> float:
    """How uncertain (1 sigma, degrees) the direction from keyframe ``first`` to ``second`` (window positions 0
    and 1) is after their bundle adjustment ``graph`` solved as ``result``: the largest spread of the second
    keyframe's position across that direction (its marginal covariance, scaled by the mean squared residual of
    an observation, so that it holds for any pixel noise) over the baseline's length; infinite where gtsam
    cannot tell (an indeterminate system)."""
    try:
        covariance = gtsam.Marginals(graph, result).marginalCovariance(gtsam.symbol("x", 1))[3:, 3:]
    except RuntimeError:
        return float("inf")
    # gtsam's pose tangent holds the position in the camera's own frame: the baseline too
    baseline = second.T_world_cam[:3, :3].T @ (second.T_world_cam[:3, 3] - first.T_world_cam[:3, 3])
    length = float(np.linalg.norm(baseline))
    across = np.eye(3) - np.outer(baseline, baseline) / max(length**2, 1e-24)
    spread = np.linalg.eigvalsh(across @ covariance @ across).max()
    residual = 2 * graph.error(result) / max(graph.size(), 1)
    return float(np.degrees(np.sqrt(max(spread * residual, 0.0)) / max(length, 1e-12)))
