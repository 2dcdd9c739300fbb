"""Real photographs and their one split: benchmark, training and validation.

- ``BENCHMARK`` photographs texture the simulated worlds (``sim.world``) and make the real-image
  evaluation (``deepslam eval realimages``); no training ever reads them.
- Every other photograph (scikit-image's and matplotlib's remaining samples, and any folder of
  photographs a user names) goes to training or validation by a hash of its group name, so the split
  never depends on what else is in the folder. A group is a sub-folder of a named folder (the variants of
  one wallpaper stay together) or a single file at its top.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from deepslam.errors import InputError

WORLD_TEXTURES = (
    "camera", "brick", "grass", "gravel", "coins", "text", "page", "clock", "astronaut", "coffee", "chelsea", "rocket",
)  # fmt: skip
"""scikit-image photographs the simulated worlds are textured with (``sim.world``)."""
REAL_IMAGE_EVALUATION = (
    "camera", "brick", "coins", "text", "page", "clock", "astronaut", "coffee", "chelsea", "rocket", "checkerboard",
)  # fmt: skip
"""scikit-image photographs of ``deepslam eval realimages``."""
BENCHMARK = (*dict.fromkeys(WORLD_TEXTURES + REAL_IMAGE_EVALUATION), "cat")
"""Every benchmark photograph (``cat`` is ``chelsea``): never trained or validated on."""

BUILTIN = {  # name -> loader of an image shipped inside an installed package (no download)
    **{f"skimage:{name}": ("skimage", name) for name in (
        "cell", "colorwheel", "horse", "hubble_deep_field", "immunohistochemistry", "logo", "moon", "retina",
        "shepp_logan_phantom",
    )},
    "matplotlib:grace_hopper": ("matplotlib", "grace_hopper.jpg"),
    "matplotlib:Minduka_Present_Blue_Pack": ("matplotlib", "Minduka_Present_Blue_Pack.png"),
}  # fmt: skip
VALIDATION_SHARE = 0.15
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".webp", ".bmp", ".tif", ".tiff")


@dataclass(frozen=True)
class Photo:
    """A photograph: ``name`` (unique, stable), ``group`` (what the split hashes) and where it comes from."""

    name: str
    group: str
    path: Path | None = None  # a file, or None for a built-in sample

    def load(self) -> np.ndarray:
        """The photograph as uint8 grayscale (H, W); ValueError if it cannot be read."""
        image = _read_builtin(self.name) if self.path is None else cv2.imread(str(self.path), cv2.IMREAD_UNCHANGED)
        if image is None:
            raise InputError(f"cannot read the image {self.path or self.name}")
        return to_gray(image)


def to_gray(image: np.ndarray) -> np.ndarray:
    """uint8 grayscale (H, W) of a grey, RGB(A) or 16-bit image."""
    image = np.asarray(image)
    if image.dtype == np.uint16:
        image = (image / 257).astype(np.uint8)
    if image.dtype != np.uint8:
        image = np.clip(image * (255 if image.max() <= 1 else 1), 0, 255).astype(np.uint8)
    if image.ndim == 3:
        image = cv2.cvtColor(image[..., :3], cv2.COLOR_RGB2GRAY) if image.shape[2] >= 3 else image[..., 0]
    return image


def _read_builtin(name: str) -> np.ndarray:
    package, item = BUILTIN[name]
    if package == "skimage":
        import skimage.data

        return getattr(skimage.data, item)()
    import matplotlib.cbook

    return cv2.cvtColor(cv2.imread(str(matplotlib.cbook.get_sample_data(item, asfileobj=False))), cv2.COLOR_BGR2RGB)


def in_validation(group: str) -> bool:
    """The split, in one place: a stable hash of the group name puts ``VALIDATION_SHARE`` of the groups
    in validation."""
    digest = int(hashlib.sha256(group.encode()).hexdigest()[:8], 16)
    return digest / 0xFFFFFFFF < VALIDATION_SHARE


def folder_photos(folder: str | Path) -> list[Photo]:
    """The photographs under ``folder`` (recursively), sorted; ValueError if there are none."""
    root = Path(folder)
    if not root.is_dir():
        raise InputError(f"no folder of photographs at {root}")
    files = sorted(p for p in root.rglob("*") if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
    if not files:
        raise InputError(f"no photographs ({', '.join(IMAGE_SUFFIXES)}) under {root}")
    photos = []
    for path in files:
        relative = path.relative_to(root)
        group = f"{root.name}/{relative.parts[0]}"
        photos.append(Photo(f"{root.name}/{relative.as_posix()}", group, path))
    return photos


def split(folders: tuple[str | Path, ...] = ()) -> dict[str, list[Photo]]:
    """{"training": [...], "validation": [...]}: the built-in samples and the photographs of ``folders``."""
    photos = [Photo(name, name) for name in BUILTIN] + [p for folder in folders for p in folder_photos(folder)]
    parts: dict[str, list[Photo]] = {"training": [], "validation": []}
    for photo in photos:
        parts["validation" if in_validation(photo.group) else "training"].append(photo)
    return parts


def random_view(
    image: np.ndarray,
    rng: np.random.Generator,
    size: tuple[int, int] = (120, 160),
    zoom: tuple[float, float] = (0.25, 1.0),
    max_rotation: float = np.pi / 6,
) -> np.ndarray:
    """A random view (H, W) = ``size`` of a photograph: a crop covering a random share ``zoom`` of the
    largest view that fits, rotated by up to ``max_rotation`` radians, resampled by area."""
    h, w = size
    ih, iw = image.shape
    fit = min(ih / h, iw / w)  # photo pixels per view pixel at the largest view
    scale = fit * rng.uniform(*zoom)
    angle = rng.uniform(-max_rotation, max_rotation)
    # keep the rotated view inside the photo: its bounding box must fit
    cos, sin = abs(np.cos(angle)), abs(np.sin(angle))
    box_w, box_h = scale * (w * cos + h * sin), scale * (w * sin + h * cos)
    shrink = min(1.0, iw / box_w, ih / box_h)
    scale *= shrink
    box_w, box_h = box_w * shrink, box_h * shrink
    cx = rng.uniform(box_w / 2, iw - box_w / 2) if iw > box_w else iw / 2
    cy = rng.uniform(box_h / 2, ih - box_h / 2) if ih > box_h else ih / 2
    # view pixel (u, v) -> photo pixel: centre + scale * R (u - centre_view)
    c, s = np.cos(angle) * scale, np.sin(angle) * scale
    u0, v0 = (w - 1) / 2, (h - 1) / 2
    M = np.array([[c, -s, cx - 0.5 - (c * u0 - s * v0)], [s, c, cy - 0.5 - (s * u0 + c * v0)]])
    source = image
    if scale > 1.5:  # area-like resampling: blur the photo to the view's sampling rate first
        source = cv2.GaussianBlur(image, (0, 0), 0.5 * np.sqrt(scale**2 - 1))
    return cv2.warpAffine(source, M, (w, h), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                          borderMode=cv2.BORDER_REFLECT_101)  # fmt: skip
