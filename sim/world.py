"""Piecewise-planar textured worlds rendered with OpenCV, with per-pixel depth (a z-buffer).

A world is a list of textured rectangles in 3D (world frame: z up). Each is drawn by mapping every
pixel's ray onto its plane and sampling the texture there, so perspective and occlusion are exact.
Landmarks are points on the surfaces; a landmark is visible when it projects inside the image and
the z-buffer there holds its depth.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal, get_args

import cv2
import numpy as np
import skimage.data

from deepslam.errors import InputError
from deepslam.geometry import in_image
from deepslam.sim import noise as noise_module
from deepslam.sim.camera import invert, project, transform
from deepslam.sim.photos import WORLD_TEXTURES
from deepslam.sim.shapes import CATEGORIES, render

CORNER_POOR = ("grass", "gravel")  # textures without corners: natural surfaces a front-end must still cope with
WorldName = Literal["plane", "room", "clutter"]
CLUTTER_BOXES = 14  # boxes of the cluttered world, 0.5-6 m in front of its first camera
WORLDS: tuple[str, ...] = get_args(WorldName)
_PHOTOS = WORLD_TEXTURES


@dataclass
class Surface:
    """A textured rectangle: ``origin`` + u * ``axis_u`` + v * ``axis_v`` for u, v in [0, 1]."""

    origin: np.ndarray
    axis_u: np.ndarray
    axis_v: np.ndarray
    texture: np.ndarray  # uint8 (h, w), texel (0, 0) at u = v = 0
    texture_name: str = ""  # the photograph's name, or "mosaic"

    @property
    def normal(self) -> np.ndarray:
        n = np.cross(self.axis_u, self.axis_v)
        return n / np.linalg.norm(n)

    def within(self, offset: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The rectangle's coordinates u and v (each 0-1 across it) of points in its plane, given as their
        ``offset`` (..., 3) from its origin, and which of them lie within its edges (...) bool."""
        u = offset @ self.axis_u / (self.axis_u @ self.axis_u)
        v = offset @ self.axis_v / (self.axis_v @ self.axis_v)
        return u, v, (u >= 0) & (u <= 1) & (v >= 0) & (v <= 1)

    def crossed(self, start: np.ndarray, end: np.ndarray) -> np.ndarray:
        """Which of the straight steps from ``start`` to ``end`` (N, 3 each, m) pass through this rectangle (N,)
        bool: from one side of its plane to the other, within its edges."""
        side_start, side_end = (start - self.origin) @ self.normal, (end - self.origin) @ self.normal
        crossing = (side_start > 0) != (side_end > 0)
        share = side_start / np.where(crossing, side_start - side_end, 1.0)  # where along the step the plane lies
        return crossing & self.within(start + share[:, None] * (end - start) - self.origin)[2]


@dataclass
class Frame:
    """A rendered view: image uint8 (H, W), depth float32 (H, W) (inf where nothing), and the visible
    landmarks' ids (N,) and pixel projections (N, 2)."""

    image: np.ndarray
    depth: np.ndarray
    landmark_ids: np.ndarray
    landmark_pixels: np.ndarray


@dataclass
class World:
    """Surfaces, landmarks (M, 3) on them, and the point trajectories orbit (``target``)."""

    name: str
    surfaces: list[Surface]
    landmarks: np.ndarray
    target: np.ndarray = field(default_factory=lambda: np.zeros(3))
    dominant_plane: tuple[np.ndarray, float] | None = None  # (unit normal n, offset c): n . X = c

    @property
    def texture(self) -> str:
        """The name of the main surface's texture (the plane's wall, the room's back wall)."""
        return self.surfaces[0].texture_name

    def passed_through(self, centres: np.ndarray) -> int | None:
        """The first of a camera's positions ``centres`` (N, 3, in order) it reached by passing through one of the
        world's surfaces (its index), or None where the path keeps to one side of every surface."""
        steps = [surface.crossed(centres[:-1], centres[1:]) for surface in self.surfaces]
        through = np.nonzero(np.any(steps, axis=0))[0] if steps else np.zeros(0, np.int64)
        return int(through[0]) + 1 if len(through) else None

    @property
    def corner_poor(self) -> bool:
        """Whether the main surface has a texture without corners (``CORNER_POOR``)."""
        return self.texture in CORNER_POOR

    def render(
        self,
        T_world_cam: np.ndarray,
        K: np.ndarray,
        size: tuple[int, int],
        rng: np.random.Generator | None = None,
        noise_s: float = 0.0,
        light: float = 1.0,
    ) -> Frame:
        """Render the view of a camera at ``T_world_cam`` with intrinsics K; ``light`` scales
        brightness and ``noise_s`` adds the photometric noise of ``sim.noise`` at that magnitude."""
        h, w = size
        T_cam_world = invert(T_world_cam)
        ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
        rays = np.stack([xs, ys, np.ones_like(xs)], -1) @ np.linalg.inv(K).T  # z = 1
        rays_world = rays @ T_world_cam[:3, :3].T
        centre = T_world_cam[:3, 3]
        image = np.zeros((h, w), np.float32)
        depth = np.full((h, w), np.inf, np.float32)
        for surface in self.surfaces:
            n = surface.normal
            with np.errstate(divide="ignore", invalid="ignore"):
                t = ((surface.origin - centre) @ n) / (rays_world @ n)
            u, v, within = surface.within(centre + rays_world * t[..., None] - surface.origin)
            mask = (t > 1e-3) & within & (t < depth)
            rows, cols = np.nonzero(mask.any(1))[0], np.nonzero(mask.any(0))[0]
            if not len(rows):
                continue
            box = np.s_[
                rows[0] : rows[-1] + 1, cols[0] : cols[-1] + 1
            ]  # sample the texture only where the surface shows
            th, tw = surface.texture.shape
            sampled = cv2.remap(
                surface.texture,
                (u[box] * (tw - 1)).astype(np.float32),
                (v[box] * (th - 1)).astype(np.float32),
                cv2.INTER_LINEAR,
                borderMode=cv2.BORDER_REFLECT,
            )
            shows = mask[box]
            image[box][shows], depth[mask] = sampled[shows], t[mask]
        image = np.clip(image * light, 0, 255).astype(np.uint8)
        if noise_s > 0:
            image = noise_module.apply(image, rng if rng is not None else np.random.default_rng(0), noise_s)
        ids, pixels = self.visible_landmarks(T_cam_world, K, depth)
        return Frame(image, depth, ids, pixels)

    def visible_landmarks(
        self, T_cam_world: np.ndarray, K: np.ndarray, depth: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Ids and pixels of landmarks inside the image and not occluded (z-buffer test)."""
        pixels, z = project(transform(T_cam_world, self.landmarks), K)
        ok = (
            (z > 1e-3)
            & np.all(np.isfinite(pixels), 1)
            & in_image(np.nan_to_num(pixels, nan=-1.0), depth.shape, margin=0.5)
        )
        ids = np.nonzero(ok)[0]
        cols, rows = np.rint(pixels[ids]).astype(int).T
        unoccluded = z[ids] <= depth[rows, cols] * 1.01 + 1e-3
        return ids[unoccluded], pixels[ids[unoccluded]]


def photo(name: str, size: tuple[int, int]) -> np.ndarray:
    """A grayscale photograph shipped with scikit-image (``skimage.data.<name>``), resized to ``size`` (H, W)."""
    image = getattr(skimage.data, name)()
    if image.ndim == 3:
        image = cv2.cvtColor(image[..., :3], cv2.COLOR_RGB2GRAY)
    return cv2.resize(image, (size[1], size[0]), interpolation=cv2.INTER_AREA)


def _texture(rng: np.random.Generator, size: int = 384, tiles: int = 4) -> tuple[np.ndarray, str]:
    """A texture and its name: a real photograph shipped with scikit-image (2/3 of the time) or a mosaic
    of ``tiles`` x ``tiles`` Synthetic Shapes renders (each a tile of its own category and background)."""
    if rng.random() < 2 / 3:
        name = str(rng.choice(_PHOTOS))
        return photo(name, (size, size)), name
    tile = size // tiles
    rows = [
        np.hstack([render(str(rng.choice(CATEGORIES[:8])), rng, (tile, tile))[0] for _ in range(tiles)])
        for _ in range(tiles)
    ]
    return np.vstack(rows), "mosaic"


def _rectangle(centre, axis_u, axis_v, rng) -> Surface:
    centre, axis_u, axis_v = (np.asarray(a, np.float64) for a in (centre, axis_u, axis_v))
    return Surface(centre - axis_u / 2 - axis_v / 2, axis_u, axis_v, *_texture(rng))


def _box(centre, size, rng) -> list[Surface]:
    """Five faces (no bottom) of an axis-aligned box standing on its base."""
    cx, cy, cz = centre
    sx, sy, sz = size
    return [
        _rectangle((cx, cy - sy / 2, cz), (sx, 0, 0), (0, 0, -sz), rng),
        _rectangle((cx, cy + sy / 2, cz), (-sx, 0, 0), (0, 0, -sz), rng),
        _rectangle((cx - sx / 2, cy, cz), (0, -sy, 0), (0, 0, -sz), rng),
        _rectangle((cx + sx / 2, cy, cz), (0, sy, 0), (0, 0, -sz), rng),
        _rectangle((cx, cy, cz + sz / 2), (sx, 0, 0), (0, sy, 0), rng),
    ]


def _landmarks(surfaces: list[Surface], rng: np.random.Generator, density: float) -> np.ndarray:
    """Random points on the surfaces, ``density`` per square unit."""
    points = []
    for s in surfaces:
        area = np.linalg.norm(np.cross(s.axis_u, s.axis_v))
        uv = rng.random((max(1, int(area * density)), 2))
        points.append(s.origin + uv[:, :1] * s.axis_u + uv[:, 1:] * s.axis_v)
    return np.vstack(points)


def _clutter(rng: np.random.Generator) -> list[Surface]:
    """A far wall, a floor and ``CLUTTER_BOXES`` boxes of many sizes at many depths, no side walls (open
    space left and right), a corridor along x = 0 kept clear for a camera moving forward."""
    surfaces = [
        _rectangle((0, 6.0, 0.8), (8, 0, 0), (0, 0, -4.0), rng),  # far wall, 8 m from the first camera
        _rectangle((0, 1.5, -1.2), (8, 0, 0), (0, 9, 0), rng),  # floor
    ]
    placed = 0
    while placed < CLUTTER_BOXES:
        size = rng.uniform([0.3, 0.3, 0.3], [1.0, 1.0, 1.6])
        x, y = rng.uniform(-3.0, 3.0), rng.uniform(-1.5, 5.0)
        if abs(x) < 0.6 + size[0] / 2 and y < 2.5:  # the corridor of the forward path
            continue
        surfaces += _box((x, y, -1.2 + size[2] / 2), size, rng)
        placed += 1
    return surfaces


def make(name: str, seed: int = 0, landmark_density: float = 150.0) -> World:
    """A world by name: "plane" (one textured wall at y = 0 facing -y: the homography case), "room" (back
    wall, side walls, floor and boxes at different depths: a dominant back wall) or "clutter" (boxes at
    0.5-6 m before a far wall and over a floor, open at the sides: no dominant plane).
    Cameras of ``sim.trajectories`` look at ``target`` from about y = -2."""
    if name not in WORLDS:
        raise InputError(f"unknown world {name!r}; expected one of {', '.join(WORLDS)}")
    rng = np.random.default_rng(seed)
    if name == "clutter":
        surfaces = _clutter(rng)
        return World(name, surfaces, _landmarks(surfaces, rng, landmark_density), np.array([0.0, 2.0, -0.3]))
    if name == "plane":
        surfaces = [_rectangle((0, 0, 0), (6, 0, 0), (0, 0, -4.5), rng)]
        return World(
            name, surfaces, _landmarks(surfaces, rng, landmark_density), np.zeros(3), (np.array([0.0, 1.0, 0.0]), 0.0)
        )
    surfaces = [
        _rectangle((0, 1.5, 0.3), (6, 0, 0), (0, 0, -3.0), rng),  # back wall
        _rectangle((-3, -0.5, 0.3), (0, -4, 0), (0, 0, -3.0), rng),  # left wall
        _rectangle((3, -0.5, 0.3), (0, 4, 0), (0, 0, -3.0), rng),  # right wall
        _rectangle((0, -0.5, -1.2), (6, 0, 0), (0, 4, 0), rng),  # floor
    ]
    for _ in range(3):
        size = rng.uniform(0.4, 0.9, 3)
        surfaces += _box((rng.uniform(-1.5, 1.5), rng.uniform(-0.2, 1.0), -1.2 + size[2] / 2), size, rng)
    return World(
        name,
        surfaces,
        _landmarks(surfaces, rng, landmark_density),
        np.array([0.0, 0.5, -0.3]),
        (np.array([0.0, 1.0, 0.0]), 1.5),
    )
