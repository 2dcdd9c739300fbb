"""Photometric noise of the paper's eight kinds, and the noise-magnitude interpolation.

Every function takes a uint8 HxW image and a ``numpy.random.Generator`` and returns a new uint8 image.
Magnitude ``s``: 0 is the clean image, 1 full noise, 2 pure random noise; in between the images are
linearly interpolated (the paper's "Effect of Noise Magnitude").
"""

from __future__ import annotations

from typing import Callable

import cv2
import numpy as np

from deepslam.errors import InputError

Noise = Callable[[np.ndarray, np.random.Generator], np.ndarray]


def _to_uint8(image: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(image), 0, 255).astype(np.uint8)


def brightness(image: np.ndarray, rng: np.random.Generator, max_delta: float = 75.0) -> np.ndarray:
    """Add one random offset in [-max_delta, max_delta] (grey levels) to every pixel."""
    return _to_uint8(image.astype(np.float32) + rng.uniform(-max_delta, max_delta))


def contrast(image: np.ndarray, rng: np.random.Generator, factors: tuple[float, float] = (0.3, 1.8)) -> np.ndarray:
    """Scale deviations from the mean grey level by a random factor."""
    pixels = image.astype(np.float32)
    mean = pixels.mean()
    return _to_uint8((pixels - mean) * rng.uniform(*factors) + mean)


def gaussian_noise(image: np.ndarray, rng: np.random.Generator, max_sigma: float = 15.0) -> np.ndarray:
    """Add zero-mean Gaussian noise with a random sigma up to ``max_sigma`` grey levels."""
    sigma = rng.uniform(0.0, max_sigma)
    return _to_uint8(image.astype(np.float32) + rng.normal(0.0, sigma, image.shape).astype(np.float32))


def speckle(image: np.ndarray, rng: np.random.Generator, max_prob: float = 0.0035) -> np.ndarray:
    """Salt-and-pepper noise: each pixel set to 0 or 255 with a random probability up to ``max_prob``."""
    prob = rng.uniform(0.0, max_prob)
    draw = rng.random(image.shape)
    out = image.copy()
    out[draw < prob / 2] = 0
    out[(draw >= prob / 2) & (draw < prob)] = 255
    return out


def shade(
    image: np.ndarray, rng: np.random.Generator, transparency: tuple[float, float] = (-0.5, 0.8), max_ellipses: int = 8
) -> np.ndarray:
    """Additive shade: blurred random ellipses darken (or lighten) parts of the image."""
    h, w = image.shape
    small = np.zeros((h // 4, w // 4), np.float32)
    for _ in range(rng.integers(1, max_ellipses + 1)):
        centre = (int(rng.integers(0, small.shape[1])), int(rng.integers(0, small.shape[0])))
        axes = (int(rng.integers(2, max(3, small.shape[1] // 3))), int(rng.integers(2, max(3, small.shape[0] // 3))))
        cv2.ellipse(small, centre, axes, float(rng.uniform(0, 180)), 0, 360, 1.0, -1)
    mask = cv2.resize(cv2.GaussianBlur(small, (0, 0), rng.uniform(1.5, 4.0)), (w, h), interpolation=cv2.INTER_LINEAR)
    alpha = rng.uniform(*transparency)
    return _to_uint8(image.astype(np.float32) * (1.0 - alpha * mask))


def gaussian_blur(image: np.ndarray, rng: np.random.Generator, max_sigma: float = 1.5) -> np.ndarray:
    """Blur with a Gaussian of random sigma in [0.3, max_sigma] pixels."""
    return cv2.GaussianBlur(image, (0, 0), rng.uniform(0.3, max_sigma))


def motion_blur(image: np.ndarray, rng: np.random.Generator, max_kernel: int = 7) -> np.ndarray:
    """Blur along a random direction with a line kernel of odd length up to ``max_kernel``."""
    size = int(rng.choice(np.arange(3, max_kernel + 1, 2)))
    kernel = np.zeros((size, size), np.float32)
    kernel[size // 2, :] = 1.0
    rotation = cv2.getRotationMatrix2D(((size - 1) / 2, (size - 1) / 2), rng.uniform(0, 180), 1.0)
    kernel = cv2.warpAffine(kernel, rotation, (size, size))
    return cv2.filter2D(image, -1, kernel / kernel.sum(), borderType=cv2.BORDER_REFLECT_101)


def random_noise(shape: tuple[int, int], rng: np.random.Generator) -> np.ndarray:
    """A pure random-noise image: uniform noise smoothed at a random scale, full contrast."""
    h, w = shape
    factor = int(rng.choice([1, 2, 4, 8]))
    small = rng.random((max(1, h // factor), max(1, w // factor))).astype(np.float32)
    noise = cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC) if factor > 1 else small
    noise -= noise.min()
    return _to_uint8(255.0 * noise / max(float(noise.max()), 1e-6))


KINDS: dict[str, Noise] = {
    "brightness": brightness,
    "contrast": contrast,
    "gaussian": gaussian_noise,
    "speckle": speckle,
    "shade": shade,
    "blur": gaussian_blur,
    "motion_blur": motion_blur,
}
"""The paper's noise types, each usable on its own; ``full_noise`` applies them all."""


def full_noise(image: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Apply every noise kind in a random order (the paper's heavy training and "noisy" noise)."""
    out = image
    for index in rng.permutation(len(KINDS)):
        out = list(KINDS.values())[index](out, rng)
    return out


def apply(image: np.ndarray, rng: np.random.Generator, s: float = 1.0, kind: str = "full") -> np.ndarray:
    """Noise of ``kind`` (one of ``KINDS`` or "full") at magnitude ``s`` in [0, 2].

    s in [0, 1] blends the clean image with its noisy version; s in (1, 2] blends the noisy version
    with pure random noise.
    """
    if kind != "full" and kind not in KINDS:
        raise InputError(f"unknown noise kind {kind!r}; expected 'full' or one of {sorted(KINDS)}")
    if not 0.0 <= s <= 2.0:
        raise InputError(f"noise magnitude s must lie in [0, 2], got {s}")
    image = np.asarray(image)
    if image.ndim != 2 or image.dtype != np.uint8:
        raise InputError(f"expected a grayscale uint8 HxW image, got {image.dtype} of shape {image.shape}")
    if s == 0.0:
        return image.copy()
    noisy = (full_noise if kind == "full" else KINDS[kind])(image, rng).astype(np.float32)
    if s <= 1.0:
        return _to_uint8((1.0 - s) * image + s * noisy)
    return _to_uint8((2.0 - s) * noisy + (s - 1.0) * random_noise(image.shape, rng))


def relit_sequence(image: np.ndarray, frames: int, rng: np.random.Generator) -> list[np.ndarray]:
    """A static camera's view of ``image`` under changing light: a point light moving across the
    scene (a broad Gaussian lobe), slow global brightness and gamma changes, and a little sensor
    noise (sigma 2 grey levels). Returns ``frames`` uint8 images of the same size."""
    h, w = image.shape
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    start, end = rng.uniform([0, 0], [w, h]), rng.uniform([0, 0], [w, h])
    radius = rng.uniform(0.3, 0.6) * max(h, w)
    phase = rng.uniform(0, 2 * np.pi)
    base = image.astype(np.float32) / 255.0
    out = []
    for i in range(frames):
        t = i / max(frames - 1, 1)
        cx, cy = start + t * (end - start)
        light = 0.5 + 0.8 * np.exp(-((xs - cx) ** 2 + (ys - cy) ** 2) / (2 * radius**2))
        gain = 1.0 + 0.25 * np.sin(2 * np.pi * t + phase)
        gamma = 1.0 + 0.3 * np.sin(4 * np.pi * t + phase / 2)
        frame = 255.0 * np.clip(base * light * gain, 0, 1) ** gamma + rng.normal(0, 2.0, (h, w))
        out.append(_to_uint8(frame))
    return out
