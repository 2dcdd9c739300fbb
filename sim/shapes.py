"""Synthetic Shapes: simple geometry rendered with OpenCV, with exact ground-truth corners.

Shapes are drawn at ``SUPERSAMPLE`` times the output resolution with sub-pixel vertices and then
area-downscaled, so edges are anti-aliased and corners are sub-pixel accurate. Corners that are hidden
or outside the image are not labels. Coordinates follow the project convention: float (x, y), the
centre of the top-left pixel at (0, 0).
"""

from __future__ import annotations

from typing import Callable, Iterator

import cv2
import numpy as np

from deepslam.errors import InputError
from deepslam.geometry import in_image
from deepslam.sim.homography import HomographyConfig, sample_homography, warp_image_and_points
from deepslam.sim.noise import full_noise, random_noise

CATEGORIES: tuple[str, ...] = (
    "triangles",
    "quadrilaterals",
    "stars",
    "lines",
    "checkerboards",
    "cubes",
    "stripes",
    "multiple_shapes",
    "ellipses",
    "noise",
)
"""The ten categories; the last two ("ellipses", "noise") have no corners."""

DEFAULT_WARP = HomographyConfig()  # the training images' homographic warps
SUPERSAMPLE = 4
_SHIFT = 4  # OpenCV fixed-point bits for sub-pixel drawing
_MIN_CONTRAST = 50


class _Canvas:
    """A supersampled drawing surface that takes low-resolution pixel coordinates."""

    def __init__(self, background: np.ndarray):
        h, w = background.shape
        self.size = (h, w)
        self.image = cv2.resize(background, (w * SUPERSAMPLE, h * SUPERSAMPLE), interpolation=cv2.INTER_LINEAR)

    def _fixed(self, points: np.ndarray) -> np.ndarray:
        hi = (np.asarray(points, np.float64) + 0.5) * SUPERSAMPLE - 0.5
        return np.rint(hi * (1 << _SHIFT)).astype(np.int32)

    def polygon(self, vertices: np.ndarray, colour: int) -> None:
        cv2.fillPoly(self.image, [self._fixed(vertices)], int(colour), cv2.LINE_8, _SHIFT)

    def line(self, a: np.ndarray, b: np.ndarray, colour: int, thickness: float) -> None:
        pa, pb = self._fixed(a), self._fixed(b)
        cv2.line(
            self.image,
            tuple(int(v) for v in pa),
            tuple(int(v) for v in pb),
            int(colour),
            max(1, int(round(thickness * SUPERSAMPLE))),
            cv2.LINE_8,
            _SHIFT,
        )

    def ellipse(self, centre: np.ndarray, axes: tuple[float, float], angle: float, colour: int) -> None:
        c = tuple(int(v) for v in self._fixed(centre))
        ax = tuple(int(round(a * SUPERSAMPLE * (1 << _SHIFT))) for a in axes)
        cv2.ellipse(self.image, c, ax, angle, 0, 360, int(colour), -1, cv2.LINE_8, _SHIFT)

    def result(self) -> np.ndarray:
        h, w = self.size
        return cv2.resize(self.image, (w, h), interpolation=cv2.INTER_AREA)


def _background(rng: np.random.Generator, size: tuple[int, int]) -> tuple[np.ndarray, int]:
    """A smooth, textured, non-uniform background and its mean grey level."""
    h, w = size
    mean = int(rng.integers(0, 256))
    texture = cv2.resize(
        rng.random((max(2, h // 16), max(2, w // 16))).astype(np.float32), (w, h), interpolation=cv2.INTER_CUBIC
    )
    amplitude = rng.uniform(0, 40)
    gradient = np.linspace(-1, 1, w, dtype=np.float32)[None, :] * rng.uniform(-20, 20)
    image = mean + amplitude * (texture - 0.5) + gradient
    return np.clip(image, 0, 255).astype(np.uint8), mean


def _colour(rng: np.random.Generator, away_from: int) -> int:
    """A grey level at least ``_MIN_CONTRAST`` away from ``away_from``."""
    choices = np.concatenate(
        [np.arange(0, max(0, away_from - _MIN_CONTRAST)), np.arange(min(256, away_from + _MIN_CONTRAST), 256)]
    )
    return int(rng.choice(choices))


def _angles_ok(vertices: np.ndarray, min_angle_deg: float) -> bool:
    """True if every interior angle of a polygon is at least ``min_angle_deg``."""
    n = len(vertices)
    for i in range(n):
        a = vertices[i - 1] - vertices[i]
        b = vertices[(i + 1) % n] - vertices[i]
        cos = a @ b / (np.linalg.norm(a) * np.linalg.norm(b) + 1e-9)
        if np.degrees(np.arccos(np.clip(cos, -1, 1))) < min_angle_deg:
            return False
    return True


def _random_polygon(rng: np.random.Generator, n: int, centre: np.ndarray, radius: float) -> np.ndarray:
    """A convex-ish polygon of n vertices around ``centre`` with well-separated angles."""
    for _ in range(100):
        angles = np.sort(rng.uniform(0, 2 * np.pi, n))
        gaps = np.diff(np.concatenate([angles, angles[:1] + 2 * np.pi]))
        if gaps.min() < 0.6 * 2 * np.pi / n / 1.5:
            continue
        radii = radius * rng.uniform(0.6, 1.0, n)
        vertices = centre + np.stack([np.cos(angles), np.sin(angles)], 1) * radii[:, None]
        if _angles_ok(vertices, 25.0) and _is_convex(vertices):
            return vertices
    return centre + radius * np.array([[np.cos(a), np.sin(a)] for a in np.linspace(0, 2 * np.pi, n, endpoint=False)])


def _is_convex(vertices: np.ndarray) -> bool:
    edges = np.roll(vertices, -1, 0) - vertices
    cross = edges[:, 0] * np.roll(edges, -1, 0)[:, 1] - edges[:, 1] * np.roll(edges, -1, 0)[:, 0]
    return bool(np.all(cross > 0) or np.all(cross < 0))


def _centre_and_radius(
    rng: np.random.Generator, size: tuple[int, int], low: float, high: float
) -> tuple[np.ndarray, float]:
    h, w = size
    radius = rng.uniform(low, high) * min(h, w)
    centre = rng.uniform([radius * 0.6, radius * 0.6], [w - radius * 0.6, h - radius * 0.6])
    return centre, radius


def _polygon(n: int) -> Callable:
    def draw(canvas: _Canvas, rng: np.random.Generator, mean: int) -> np.ndarray:
        centre, radius = _centre_and_radius(rng, canvas.size, 0.25, 0.45)
        vertices = _random_polygon(rng, n, centre, radius)
        canvas.polygon(vertices, _colour(rng, mean))
        return vertices

    return draw


def _segments_intersect(p1, p2, q1, q2) -> bool:
    def orient(a, b, c):
        return np.sign((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]))

    return orient(p1, p2, q1) != orient(p1, p2, q2) and orient(q1, q2, p1) != orient(q1, q2, p2)


def _point_segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    ab = b - a
    t = np.clip((p - a) @ ab / (ab @ ab + 1e-9), 0, 1)
    return float(np.linalg.norm(p - (a + t * ab)))


def _draw_lines(canvas: _Canvas, rng: np.random.Generator, mean: int) -> np.ndarray:
    """1-4 non-intersecting thick segments; corners are their endpoints."""
    h, w = canvas.size
    segments: list[tuple[np.ndarray, np.ndarray]] = []
    for _ in range(int(rng.integers(1, 5))):
        for _ in range(50):
            a = rng.uniform([0, 0], [w - 1, h - 1])
            b = rng.uniform([0, 0], [w - 1, h - 1])
            if np.linalg.norm(a - b) < 0.25 * min(h, w):
                continue
            clear = all(
                not _segments_intersect(a, b, c, d)
                and min(_point_segment_distance(p, c, d) for p in (a, b)) > 6
                and min(_point_segment_distance(p, a, b) for p in (c, d)) > 6
                for c, d in segments
            )
            if clear:
                segments.append((a, b))
                canvas.line(a, b, _colour(rng, mean), rng.uniform(1.0, 3.0))
                break
    return np.array([p for segment in segments for p in segment]).reshape(-1, 2)


def _draw_star(canvas: _Canvas, rng: np.random.Generator, mean: int) -> np.ndarray:
    """Rays from a centre; corners are the centre and the ray ends."""
    centre, radius = _centre_and_radius(rng, canvas.size, 0.3, 0.45)
    vertices = _random_polygon(rng, int(rng.integers(3, 6)), centre, radius)
    colour, thickness = _colour(rng, mean), rng.uniform(1.0, 2.5)
    for v in vertices:
        canvas.line(centre, v, colour, thickness)
    return np.vstack([centre[None], vertices])


def _draw_checkerboard(canvas: _Canvas, rng: np.random.Generator, mean: int) -> np.ndarray:
    """A perspective-warped checkerboard; corners are every grid vertex."""
    h, w = canvas.size
    rows, cols = int(rng.integers(3, 7)), int(rng.integers(3, 7))
    cell = min(h / rows, w / cols) * rng.uniform(0.5, 0.9)
    grid = np.stack(np.meshgrid(np.arange(cols + 1), np.arange(rows + 1)), -1).reshape(-1, 2) * cell
    board = np.array([[0, 0], [cols, 0], [cols, rows], [0, rows]], np.float64) * cell
    offset = np.array([(w - cols * cell) / 2, (h - rows * cell) / 2])
    jitter = rng.uniform(-0.15, 0.15, (4, 2)) * cell * min(rows, cols)
    H = cv2.getPerspectiveTransform(board.astype(np.float32), (board + offset + jitter).astype(np.float32))
    vertices = cv2.perspectiveTransform(grid[None].astype(np.float64), H)[0].reshape(rows + 1, cols + 1, 2)
    light, dark = _colour(rng, mean), 0
    dark = _colour(rng, light)
    for r in range(rows):
        for c in range(cols):
            quad = np.array([vertices[r, c], vertices[r, c + 1], vertices[r + 1, c + 1], vertices[r + 1, c]])
            canvas.polygon(quad, light if (r + c) % 2 else dark)
    return vertices.reshape(-1, 2)


def _draw_cube(canvas: _Canvas, rng: np.random.Generator, mean: int) -> np.ndarray:
    """A randomly rotated cube with three visible faces; corners are the seven visible vertices."""
    h, w = canvas.size
    cube = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], np.float64)
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    # An isometric-like view (three faces towards the viewer), perturbed, then spun in the image plane.
    base, _ = cv2.Rodrigues(np.array([np.arctan(1 / np.sqrt(2)), np.pi / 4, 0.0]))
    tweak, _ = cv2.Rodrigues(rng.uniform(-0.25, 0.25, 3))
    spin, _ = cv2.Rodrigues(np.array([0, 0, rng.uniform(0, 2 * np.pi)]))
    rotated = cube @ (spin @ tweak @ base).T
    scale = min(h, w) * rng.uniform(0.18, 0.3)
    centre = rng.uniform([0.35 * w, 0.35 * h], [0.65 * w, 0.65 * h])
    projected = rotated[:, :2] * scale + centre
    visible: set[int] = set()
    colours = [_colour(rng, mean) for _ in faces]
    for face, colour in zip(faces, colours, strict=False):
        a, b, c = (rotated[i] for i in face[:3])
        if np.cross(b - a, c - a)[2] < 0:  # faces the viewer (z into the screen)
            canvas.polygon(projected[list(face)], colour)
            visible.update(face)
    return projected[sorted(visible)]


def _draw_stripes(canvas: _Canvas, rng: np.random.Generator, mean: int) -> np.ndarray:
    """Parallel stripes inside a rotated rectangle; corners are where stripe edges meet its sides."""
    h, w = canvas.size
    width = rng.uniform(0.5, 0.8) * w
    height = rng.uniform(0.4, 0.7) * h
    edges = np.sort(rng.uniform(0, width, int(rng.integers(3, 8)) * 2))
    edges = edges[np.concatenate([[True], np.diff(edges) > 5])]
    angle = rng.uniform(-np.pi / 6, np.pi / 6)
    rotation = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    centre = np.array([(w - 1) / 2, (h - 1) / 2]) + rng.uniform(-0.1, 0.1, 2) * [w, h]

    def place(points):
        return (np.asarray(points, np.float64) - [width / 2, height / 2]) @ rotation.T + centre

    colour = _colour(rng, mean)
    corners = []
    for left, right in zip(edges[0::2], edges[1::2], strict=False):
        quad = place([[left, 0], [right, 0], [right, height], [left, height]])
        canvas.polygon(quad, colour)
        corners.append(quad)
    return np.vstack(corners) if corners else np.zeros((0, 2))


def _draw_multiple(canvas: _Canvas, rng: np.random.Generator, mean: int) -> np.ndarray:
    """Several non-overlapping polygons and ellipses; corners are the polygon vertices."""
    h, w = canvas.size
    placed: list[tuple[np.ndarray, float]] = []
    corners = []
    for _ in range(int(rng.integers(2, 6))):
        for _ in range(30):
            radius = rng.uniform(0.1, 0.22) * min(h, w)
            centre = rng.uniform([radius, radius], [w - radius, h - radius])
            if all(np.linalg.norm(centre - c) > radius + r + 2 for c, r in placed):
                placed.append((centre, radius))
                colour = _colour(rng, mean)
                if rng.random() < 0.25:
                    canvas.ellipse(centre, (radius, radius * rng.uniform(0.4, 1.0)), rng.uniform(0, 180), colour)
                else:
                    vertices = _random_polygon(rng, int(rng.integers(3, 5)), centre, radius)
                    canvas.polygon(vertices, colour)
                    corners.append(vertices)
                break
    return np.vstack(corners) if corners else np.zeros((0, 2))


def _draw_ellipses(canvas: _Canvas, rng: np.random.Generator, mean: int) -> np.ndarray:
    """Several ellipses (a negative category: no corners)."""
    h, w = canvas.size
    placed: list[tuple[np.ndarray, float]] = []
    for _ in range(int(rng.integers(1, 6))):
        axes = (rng.uniform(0.05, 0.3) * min(h, w), rng.uniform(0.05, 0.3) * min(h, w))
        centre = rng.uniform([0, 0], [w, h])
        if all(np.linalg.norm(centre - c) > max(axes) + r + 2 for c, r in placed):  # no junctions
            placed.append((centre, max(axes)))
            canvas.ellipse(centre, axes, rng.uniform(0, 180), _colour(rng, mean))
    return np.zeros((0, 2))


_DRAW: dict[str, Callable] = {
    "triangles": _polygon(3),
    "quadrilaterals": _polygon(4),
    "stars": _draw_star,
    "lines": _draw_lines,
    "checkerboards": _draw_checkerboard,
    "cubes": _draw_cube,
    "stripes": _draw_stripes,
    "multiple_shapes": _draw_multiple,
    "ellipses": _draw_ellipses,
}


def check_size(size: tuple[int, int]) -> tuple[int, int]:
    """Validate an image size (H, W): positive and divisible by 8 (the networks' cell size)."""
    if len(size) != 2 or min(size) <= 0 or size[0] % 8 or size[1] % 8:
        raise InputError(f"image size (H, W) must be positive and divisible by 8, got {tuple(size)}")
    return int(size[0]), int(size[1])


def render(
    category: str, rng: np.random.Generator, size: tuple[int, int] = (120, 160)
) -> tuple[np.ndarray, np.ndarray]:
    """Render one image of ``category``.

    Returns (image uint8 (H, W), corners float32 (K, 2) in (x, y) pixels); K is 0 for the negative
    categories "ellipses" and "noise".
    """
    if category not in CATEGORIES:
        raise InputError(f"unknown category {category!r}; expected one of {', '.join(CATEGORIES)}")
    size = check_size(size)
    if category == "noise":
        return random_noise(size, rng), np.zeros((0, 2), np.float32)
    background, mean = _background(rng, size)
    canvas = _Canvas(background)
    corners = np.asarray(_DRAW[category](canvas, rng, mean), np.float64).reshape(-1, 2)
    image = cv2.GaussianBlur(canvas.result(), (0, 0), 0.5) if rng.random() < 0.5 else canvas.result()
    return image, corners[in_image(corners, size, margin=0.5)].astype(np.float32)


def training_stream(
    rng: np.random.Generator,
    size: tuple[int, int] = (120, 160),
    homography: HomographyConfig | None = DEFAULT_WARP,
    clean_share: float = 0.0,
) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """An endless stream of (image, corners) for training: a random category, a random homographic
    warp, then the full photometric noise, except for a ``clean_share`` (0..1) of the images, which
    stay clean. Never the same example twice for a fresh ``rng``."""
    if not 0.0 <= clean_share <= 1.0:
        raise InputError(f"clean_share must lie in [0, 1], got {clean_share}")
    while True:
        image, corners = render(CATEGORIES[int(rng.integers(len(CATEGORIES)))], rng, size)
        if homography is not None:
            image, corners = warp_image_and_points(image, corners, sample_homography(rng, size, homography))
        clean = clean_share > 0 and rng.random() < clean_share  # no draw at 0: older runs resume unchanged
        yield (image if clean else full_noise(image, rng)), corners


def evaluation_set(
    per_category: int = 1000,
    seed: int = 0,
    size: tuple[int, int] = (120, 160),
    categories: tuple[str, ...] = CATEGORIES,
) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """A fixed, seeded evaluation set: ``per_category`` clean (category, image, corners) per category.

    Each category draws from its own seed stream, so a larger set extends a smaller one.
    """
    items = []
    for category in categories:
        rng = np.random.default_rng([seed, CATEGORIES.index(category)])
        items.extend((category, *render(category, rng, size)) for _ in range(per_category))
    return items
