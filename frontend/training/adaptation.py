"""Homographic adaptation: MagicPoint for real photographs, labelled by itself (SuperPoint, DeTone et al. 2018).

A round labels random views of real photographs (``sim.photos``, training split) with the current
detector: it is run on ``warps`` random homographic warps of each view, the heatmaps are warped back
(masks eroded, so that borders do not count) and averaged, and the peaks of that average, at sub-pixel
positions, are the labels. A detector is then trained on those views (each warped again and, for a
share, given the paper's photometric noise) mixed with Synthetic Shapes, so that the paper's table
holds. Targets are soft: a sub-pixel label spreads over the pixels of its cell bilinearly, so the
network learns where within a pixel a corner lies (read back by a sub-pixel refinement of each peak:
``extract_points(refine=...)``; validation reads centroids, as every round since the first).
The next round labels with the detector the last one trained.

On disk, ``OUT/roundK/`` holds the round's label shards (``labels/``, reused while their inputs are
unchanged) and its training checkpoints; every stage resumes.
"""

from __future__ import annotations

import hashlib
import json
import logging
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Literal

import cv2
import numpy as np
import torch

from deepslam.errors import InputError
from deepslam.frontend.cells import CELL
from deepslam.frontend.magicpoint import VARIANTS, MagicPoint, MagicPointConfig, MagicPointNet, cells_to_heatmap
from deepslam.frontend.nets import load_checkpoint
from deepslam.frontend.points import Subpixel, extract_points
from deepslam.frontend.training.loop import LoopConfig, train
from deepslam.frontend.training.magicpoint import cell_labels
from deepslam.frontend.training.surgery import load_weights
from deepslam.geometry import in_image, warp_points
from deepslam.progress import progress_bar
from deepslam.sim import noise, photos
from deepslam.sim.homography import HomographyConfig, sample_homography, warp_image
from deepslam.sim.shapes import training_stream

log = logging.getLogger(__name__)

SHARD = 200  # labelled views per file on disk


@dataclass(frozen=True)
class AdaptConfig(LoopConfig):
    """One round's training (``LoopConfig``: ``iterations`` steps per round) and the labelling."""

    iterations: int = 4000
    lr: float = 2e-4
    rounds: int = field(default=2, metadata={"help": "rounds of labelling and training", "min": 1, "max": 100})
    views: int = field(
        default=2000,
        metadata={"help": "labelled random views of the photographs per round", "min": 1, "max": 1_000_000},
    )
    warps: int = field(
        default=64,
        metadata={"help": "homographic warps per view (the identity included; SuperPoint: 100)", "min": 1, "max": 1000},
    )
    label_warp: tuple[float, float, float, float] = (0.1, 0.35, 0.2, 0.1)  # translation, rotation, zoom, jitter
    train_warp: tuple[float, float, float, float] = (0.05, 0.2, 0.15, 0.05)  # each view warped again in training
    erode: int = 6  # pixels taken off each warped mask's edge before averaging
    label_threshold: float = field(
        default=0.0015, metadata={"help": "the smallest averaged corner probability that is a label", "min": 0}
    )
    label_top_k: int = 150  # at most this many labels per view
    label_refine: Subpixel = field(
        default="centroid",
        metadata={
            "help": "sub-pixel position of each label in the averaged heatmap: centroid (of the peak's 3x3 "
            "neighbourhood; S-HA v1-v3), parabola (through the peak and its neighbours; more precise, see the "
            "S-HA model card) or none (the peak's pixel)"
        },
    )
    teacher_scale: int = field(
        default=1,
        metadata={
            "help": "the labelling detector sees each view enlarged this many times (its warps averaged at that "
            "resolution, labels brought back to the view's pixels)",
            "min": 1,
            "max": 4,
        },
    )
    synthetic_share: float = field(
        default=0.375,
        metadata={"help": "share of every batch drawn from Synthetic Shapes, with its labels", "min": 0, "max": 1},
    )
    noisy_share: float = field(
        default=0.5,
        metadata={"help": "share of the photographs given the paper's full photometric noise", "min": 0, "max": 1},
    )
    photos: tuple[str, ...] = field(
        default=(),
        metadata={
            "help": "folders of photographs to train on beside the built-in samples (split into training and "
            "validation by sim.photos)",
            "metavar": "DIR",
        },
    )
    widths: tuple[int, int, int, int] = field(
        default=VARIANTS["S-HA"].widths,
        metadata={
            "help": "the trained detector's encoder widths (default S's); wider than the labelling detector's, it "
            "starts from that detector's function (its weights embedded)",
            "min": 1,
            "max": 1024,
        },
    )
    head: int = field(
        default=VARIANTS["S-HA"].head,
        metadata={
            "help": "width of the trained detector's 3x3 layer before its 65-channel head",
            "min": 1,
            "max": 4096,
        },
    )
    pool: Literal["max", "blur"] = field(
        default=VARIANTS["S-HA"].pool,
        metadata={
            "help": "the trained detector's 2x2 pooling: blur (S-HA's; anti-aliased, Zhang 2019: a max over every "
            "2x2 window, then a binomial blur sampled every second pixel, so that detections follow sub-cell "
            "motion) or max (the paper's)"
        },
    )
    shift_consistency: float = field(
        default=0.0,
        metadata={
            "help": "weight of a term that makes each photograph's heatmap follow the image within a cell: every "
            "view is also seen shifted by 0-7 px, and the square roots of the two heatmaps must agree where both "
            "see the view (0: off)",
            "min": 0,
        },
    )
    size: tuple[int, int] = (120, 160)
    validation_views: int = 2  # views per validation photograph, each seen as a jittered sequence

    def __post_init__(self):
        super().__post_init__()
        problems = [
            f"--{name.replace('_', '-')} must be at least 1, got {getattr(self, name)}"
            for name in ("rounds", "views", "warps", "label_top_k", "validation_views", "teacher_scale", "head")
            if getattr(self, name) < 1
        ]
        if min(self.widths) < 1:
            problems.append(f"--widths must be at least 1, got {self.widths}")
        problems += [
            f"--{name.replace('_', '-')} must lie in [0, 1], got {getattr(self, name)}"
            for name in ("synthetic_share", "noisy_share")
            if not 0 <= getattr(self, name) <= 1
        ]
        if not (np.isfinite(self.label_threshold) and self.label_threshold >= 0) or self.erode < 0:
            problems.append("--label-threshold and --erode must be finite and at least 0")
        if not (np.isfinite(self.shift_consistency) and self.shift_consistency >= 0):
            problems.append(f"--shift-consistency must be finite and at least 0, got {self.shift_consistency}")
        if problems:
            raise InputError("; ".join(problems))


def _homography(ranges: tuple[float, float, float, float]) -> HomographyConfig:
    translation, rotation, zoom, jitter = ranges
    return HomographyConfig(translation=translation, rotation=rotation, scale=zoom, perspective=jitter)


@torch.inference_mode()
def adapted_heatmap(net: torch.nn.Module, image: np.ndarray, homographies: np.ndarray, erode: int) -> np.ndarray:
    """The detector's heatmap (H, W) of ``image`` averaged over its warps by ``homographies`` (K, 3, 3),
    each warped heatmap brought back into the image and counted only inside its eroded mask."""
    h, w = image.shape
    warped = np.stack([warp_image(image, H) for H in homographies])
    x = torch.from_numpy(warped).float().div_(255.0)[:, None].contiguous(memory_format=torch.channels_last)
    heatmaps = cells_to_heatmap(torch.softmax(net(x), dim=1)).numpy()
    kernel = np.ones((2 * erode + 1, 2 * erode + 1), np.uint8) if erode else None
    total, count = np.zeros((h, w), np.float32), np.zeros((h, w), np.float32)
    ones = np.ones((h, w), np.uint8)
    for heat, H in zip(heatmaps, homographies, strict=True):
        back = np.linalg.inv(H)
        mask = cv2.warpPerspective(ones, back, (w, h), flags=cv2.INTER_NEAREST)
        mask = cv2.erode(mask, kernel) if kernel is not None else mask
        total += cv2.warpPerspective(heat, back, (w, h), flags=cv2.INTER_LINEAR) * mask
        count += mask
    return total / np.maximum(count, 1.0)


def label_views(net: torch.nn.Module, images: np.ndarray, rng: np.random.Generator, config: AdaptConfig) -> np.ndarray:
    """Labels (N, top_k, 3) [x, y, score] of views (N, H, W), NaN rows where a view has fewer. With
    ``teacher_scale`` s > 1 each view is enlarged s times (pixel centres kept: x' = s (x + 0.5) - 0.5), its
    warps are the same homographies conjugated into the enlarged pixels, and the labels come back."""
    s = config.teacher_scale
    enlarge = np.array([[s, 0, (s - 1) / 2], [0, s, (s - 1) / 2], [0, 0, 1.0]])
    labels = np.full((len(images), config.label_top_k, 3), np.nan, np.float32)
    for i, image in enumerate(images):
        homographies = [np.eye(3)] + [
            sample_homography(rng, image.shape, _homography(config.label_warp)) for _ in range(config.warps - 1)
        ]
        h, w = image.shape
        seen = cv2.resize(image, (w * s, h * s), interpolation=cv2.INTER_LINEAR) if s > 1 else image
        warps = enlarge @ np.stack(homographies) @ np.linalg.inv(enlarge)
        heat = adapted_heatmap(net, seen, warps, config.erode * s)
        points = extract_points(heat, config.label_threshold, 4 * s, 4 * s, config.label_top_k, config.label_refine)
        points[:, :2] = (points[:, :2] + 0.5) / s - 0.5
        labels[i, : len(points)] = points
    return labels


def _file_digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()[:16]


def labelling_key(config: AdaptConfig, detector: Path, training: list[photos.Photo], round_: int) -> dict:
    """Everything the labels of a round depend on: the labelling detector's weights, the photographs, the
    options and the seed."""
    inputs = {"views", "warps", "label_warp", "erode", "label_threshold", "label_top_k", "size", "seed"}
    options = {k: v for k, v in asdict(config).items() if k in inputs}
    key = {"detector": _file_digest(detector), "photos": [p.name for p in training], "round": round_, **options}
    if config.teacher_scale != 1:  # labels of an unenlarged teacher keep the key they were made with
        key["teacher_scale"] = config.teacher_scale
    if config.label_refine != "centroid":  # likewise labels at centroids
        key["label_refine"] = config.label_refine
    return json.loads(json.dumps(key))  # as it reads back from disk (tuples become lists)


class Photographs:
    """The training photographs, loaded once and shrunk to at most ``max_side`` pixels (random views
    never need more at 120x160 or 240x320). Every group (``sim.photos``) is drawn equally often, so that
    a wallpaper shipped at ten resolutions weighs as much as a single photograph."""

    def __init__(self, chosen: list[photos.Photo], max_side: int = 1280):
        self.groups: dict[str, list[np.ndarray]] = {}
        for photo in progress_bar(chosen, desc="loading photographs", unit="photo", leave=False):
            image = photo.load()
            scale = max_side / max(image.shape)
            if scale < 1:
                image = cv2.resize(image, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
            self.groups.setdefault(photo.group, []).append(image)
        self.members = list(self.groups.values())

    def views(self, rng: np.random.Generator, count: int, size: tuple[int, int]) -> np.ndarray:
        """``count`` random views (count, H, W) uint8, each of a random photograph of a random group."""
        views = []
        for _ in range(count):
            group = self.members[int(rng.integers(len(self.members)))]
            views.append(photos.random_view(group[int(rng.integers(len(group)))], rng, size))
        return np.stack(views)


def labelled_views(
    folder: Path, net: torch.nn.Module, source: Photographs, key: dict, config: AdaptConfig
) -> tuple[np.ndarray, np.ndarray]:
    """(views (N, H, W) uint8, labels (N, K, 3)) of one round, labelled shard by shard into ``folder``;
    shards already there are reused while ``key`` matches, and all are made anew when it does not."""
    folder.mkdir(parents=True, exist_ok=True)
    key_file = folder / "key.json"
    if key_file.exists() and json.loads(key_file.read_text()) != key:
        log.info(f"{folder}: the labels' inputs changed (detector, photographs or options); labelling anew")
        for shard in folder.glob("shard_*.npz"):
            shard.unlink()
    key_file.write_text(json.dumps(key, indent=1))
    shards = (config.views + SHARD - 1) // SHARD
    views, labels = [], []
    with progress_bar(total=config.views, desc=f"labelling {folder.parent.name}", unit="view") as bar:
        for index in range(shards):
            path = folder / f"shard_{index:03d}.npz"
            count = min(SHARD, config.views - index * SHARD)
            if not path.exists():
                rng = np.random.default_rng([config.seed, key["round"], index])
                images = source.views(rng, count, config.size)
                tmp = path.with_suffix(".tmp.npz")
                np.savez_compressed(tmp, views=images, labels=label_views(net, images, rng, config))
                tmp.replace(path)
            with np.load(path) as shard:
                views.append(shard["views"])
                labels.append(shard["labels"])
            bar.update(count)
    return np.concatenate(views), np.concatenate(labels)


def soft_targets(points: list[np.ndarray], size: tuple[int, int]) -> np.ndarray:
    """Soft 65-class cell targets float32 (B, 65, H/8, W/8) of sub-pixel points (N, 2+): each point
    spreads bilinearly over the up to four pixels around it that lie in its cell (renormalised); a cell
    keeps its best-scoring point (the first, as points are sorted); empty cells are all dustbin."""
    h, w = size
    targets = np.zeros((len(points), CELL * CELL + 1, h // CELL, w // CELL), np.float32)
    targets[:, CELL * CELL] = 1.0
    for b, pts in enumerate(points):
        pts = np.asarray(pts, np.float64).reshape(-1, np.shape(pts)[-1] if np.ndim(pts) > 1 else 2)
        pts = pts[in_image(pts, size, margin=0.5)]
        taken = np.zeros((h // CELL, w // CELL), bool)
        for x, y in pts[:, :2]:
            cx, cy = int(np.rint(x)) // CELL, int(np.rint(y)) // CELL
            if taken[cy, cx]:
                continue
            taken[cy, cx] = True
            x0, y0 = int(np.floor(x)), int(np.floor(y))
            fx, fy = x - x0, y - y0
            weights = {}
            for px, py, weight in ((x0, y0, (1 - fx) * (1 - fy)), (x0 + 1, y0, fx * (1 - fy)),
                                   (x0, y0 + 1, (1 - fx) * fy), (x0 + 1, y0 + 1, fx * fy)):  # fmt: skip
                if px // CELL == cx and py // CELL == cy and weight > 0:
                    weights[(py % CELL) * CELL + px % CELL] = weight
            total = sum(weights.values())
            targets[b, CELL * CELL, cy, cx] = 0.0
            for channel, weight in weights.items():
                targets[b, channel, cy, cx] = weight / total
    return targets


def _one_hot(labels: np.ndarray) -> np.ndarray:
    """int (B, Hc, Wc) cell classes -> float32 (B, 65, Hc, Wc)."""
    return np.moveaxis(np.eye(CELL * CELL + 1, dtype=np.float32)[labels], -1, 1)


def photo_batch(
    views: np.ndarray, labels: np.ndarray, rng: np.random.Generator, count: int, config: AdaptConfig
) -> tuple[np.ndarray, np.ndarray]:
    """``count`` labelled views, each warped by a fresh random homography (labels moved with it) and,
    for a ``noisy_share``, given the full photometric noise: (images (B, H, W), soft targets)."""
    images, points = [], []
    for i in rng.integers(len(views), size=count):
        H = sample_homography(rng, config.size, _homography(config.train_warp))
        image = warp_image(views[i], H, border_value=-1)
        kept = labels[i][np.isfinite(labels[i, :, 0])]
        moved = warp_points(kept, H)
        images.append(noise.full_noise(image, rng) if rng.random() < config.noisy_share else image)
        points.append(moved)
    return np.stack(images), soft_targets(points, config.size)


SHIFT_MARGIN = 16  # pixels of the border the shift-consistency term leaves out (reflected in the shifted view)


def shifted_views(images: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Each view (B, H, W) uint8 moved right by dx and down by dy pixels, each drawn from 0-7 and not both
    0 (less than MagicPoint's 8-pixel cell), its border reflected: (moved views (B, H, W), shifts (B, 2))."""
    moved, shifts = [], []
    for image in images:
        dx, dy = 0, 0
        while not (dx or dy):
            dx, dy = (int(d) for d in rng.integers(0, CELL, 2))
        moved.append(warp_image(image, np.array([[1.0, 0, dx], [0, 1, dy], [0, 0, 1]]), border_value=-1))
        shifts.append((dx, dy))
    return np.stack(moved), np.array(shifts, np.int64).reshape(-1, 2)


def shift_disagreement(heat: torch.Tensor, heat_moved: torch.Tensor, shifts: np.ndarray) -> torch.Tensor:
    """How far heatmaps (B, H, W) of views and of the views moved by ``shifts`` (B, 2) [dx, dy] disagree:
    the squared difference of their square roots (so that weak peaks count, not just strong ones), summed
    over the pixels the two have in common ``SHIFT_MARGIN`` pixels from the border, per 8x8 cell, averaged
    over the views."""
    h, w = heat.shape[1:]
    m = SHIFT_MARGIN
    terms = []
    for view, moved, (dx, dy) in zip(heat, heat_moved, shifts.tolist(), strict=True):
        a = view[m : h - m, m : w - m].clamp_min(1e-8).sqrt()
        b = moved[m + dy : h - m + dy, m + dx : w - m + dx].clamp_min(1e-8).sqrt()
        terms.append(((a - b) ** 2).sum() / (a.numel() / (CELL * CELL)))
    return torch.stack(terms).mean()


def validation_sequences(config: AdaptConfig, validation: list[photos.Photo]) -> dict[str, list]:
    """Jittered sequences (up to 2 px a frame) of validation photographs, clean and noisy."""
    from deepslam.frontend.evaluation.detector import photo_sequences

    rng = np.random.default_rng(config.seed + 2000)
    images = [
        photos.random_view(p.load(), rng, config.size) for p in validation for _ in range(config.validation_views)
    ]
    return {
        condition: photo_sequences(images, 8, rng, noisy=condition == "noisy", jitter_px=2.0)
        for condition in ("clean", "noisy")
    }


def run(out_dir: Path, config: AdaptConfig = AdaptConfig()) -> dict:
    """All rounds of homographic adaptation into ``out_dir/roundK`` (each resumes); round 1 labels with
    ``config.init`` (default: the shipped MagicPoint S) and starts training from it. Returns the last round's
    final validation figures; the best weights of the last round are ``out_dir/round{rounds}/best.pt``."""
    from deepslam.frontend.evaluation.detector import noisy_set
    from deepslam.frontend.magicpoint import WEIGHTS
    from deepslam.sim.shapes import evaluation_set

    parts = photos.split(tuple(config.photos))
    if not parts["training"] or not parts["validation"]:
        raise InputError("homographic adaptation needs photographs for training and for validation; add --photos DIR")
    log.info(f"photographs: {len(parts['training'])} for training, {len(parts['validation'])} for validation")
    source = Photographs(parts["training"])
    sequences = validation_sequences(config, parts["validation"])
    shapes_clean = evaluation_set(10, seed=config.seed + 1000, size=config.size)
    shapes_noisy = noisy_set(shapes_clean, seed=config.seed + 1000)
    detector_weights = Path(config.init) if config.init else WEIGHTS / "magicpoint_S.pt"
    figures: dict = {}
    for round_ in range(1, config.rounds + 1):
        folder = out_dir / f"round{round_}"
        key = labelling_key(config, detector_weights, parts["training"], round_)
        trained_on = folder / "labels" / "key.json"
        if (folder / "last.pt").exists() and trained_on.exists() and json.loads(trained_on.read_text()) != key:
            raise InputError(
                f"{folder} was trained on labels of another detector, photographs or options; train into another --out"
            )
        if _finished(folder, config.iterations):  # a finished round needs neither its labels nor training
            log.info(f"{folder} has finished its {config.iterations} steps")
            detector_weights = folder / "best.pt"
            continue
        round_config = _round_config(config, round_)
        with torch.random.fork_rng():  # a wider network's new units come from the seed
            torch.manual_seed(round_config.seed)
            net = MagicPointNet(MagicPointConfig(config.widths, config.head, config.pool))
        load_weights(net, detector_weights)  # starts from the labelling detector; a misfit fails before labelling
        teacher = MagicPoint.pretrained("S-HA", path=detector_weights).net  # folded, in its own shape
        views, labels = labelled_views(folder / "labels", teacher, source, key, config)
        figures = _train_round(net, folder, views, labels, round_config, sequences, (shapes_clean, shapes_noisy))
        detector_weights = folder / "best.pt"
    return figures


def _finished(folder: Path, iterations: int) -> bool:
    last = folder / "last.pt"
    return last.exists() and load_checkpoint(last, needs=("step",))["step"] >= iterations


def _round_config(config: AdaptConfig, round_: int) -> AdaptConfig:
    """A round's training options: its own data stream (it starts from the weights that labelled it, loaded
    by ``run``, not from ``init``)."""
    return replace(config, init="", seed=config.seed + 1000 * (round_ - 1))


def _train_round(net, folder, views, labels, config, sequences, shapes) -> dict:
    from deepslam.frontend.config import EXTRACTION_PRESETS
    from deepslam.frontend.evaluation.detector import evaluate_set, sequence_repeatability

    stream = None

    def step_fn(step: int, rng: np.random.Generator, batch: int) -> dict:
        nonlocal stream
        stream = stream or training_stream(rng, config.size, clean_share=0.25)
        synthetic = round(batch * config.synthetic_share)
        images, targets = photo_batch(views, labels, rng, batch - synthetic, config)
        moved, shifts = images[:0], np.zeros((0, 2), np.int64)
        if config.shift_consistency:  # from a stream of its own: the batches stay those of a run without it
            moved, shifts = shifted_views(images, np.random.default_rng([config.seed, step]))
        if synthetic:
            shapes_images, corners = zip(*(next(stream) for _ in range(synthetic)), strict=True)
            images = np.concatenate([images, np.stack(shapes_images)])
            targets = np.concatenate([targets, _one_hot(cell_labels(list(corners), config.size, rng))])
        device = next(net.parameters()).device
        x = torch.from_numpy(np.concatenate([images, moved])).float().div_(255.0)[:, None].to(device)
        logits = net(x)
        log_p = torch.log_softmax(logits[: len(images)], dim=1)
        loss = -(torch.from_numpy(targets).to(device) * log_p).sum(1).mean()
        if len(moved):
            heat = cells_to_heatmap(torch.softmax(logits, dim=1))
            loss = loss + config.shift_consistency * shift_disagreement(heat[: len(moved)], heat[len(images) :], shifts)
        return {"loss": loss}

    def validate(model: MagicPointNet) -> dict:
        detector = MagicPoint(model, EXTRACTION_PRESETS["photo validation"])
        real = {c: sequence_repeatability(detector, s) for c, s in sequences.items()}
        shapes_detector = MagicPoint(model, EXTRACTION_PRESETS["shapes"])
        clean, noisy = (evaluate_set(shapes_detector, items)["map"] for items in shapes)
        figures = {f"rep_{c}": r["repeatability"] for c, r in real.items()}
        figures |= {f"loc_{c}": r["localization_error"] for c, r in real.items()}
        figures |= {"map_clean": clean, "map_noisy": noisy}
        figures["score"] = (figures["rep_clean"] + figures["rep_noisy"] + clean + noisy) / 4
        return figures

    return train(net, config, folder, step_fn, validate, "score")
