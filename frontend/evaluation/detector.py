"""Detector evaluation on Synthetic Shapes: the paper's table, per category, noise magnitude and type."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar, Protocol

import cv2
import numpy as np

from deepslam.frontend.evaluation.config import DetectorEvalConfig, RealImagesConfig
from deepslam.frontend.evaluation.metrics import average_precision, localization_error, match_detections, merge
from deepslam.parallel import Workers, parallel_map
from deepslam.progress import progress_bar
from deepslam.results import Result
from deepslam.sim import noise
from deepslam.sim.photos import REAL_IMAGE_EVALUATION
from deepslam.sim.world import photo

Item = tuple[str, np.ndarray, np.ndarray]  # (category, image, corners)


class Detector(Protocol):
    def detect(self, image: np.ndarray) -> np.ndarray: ...


def noisy_set(items: list[Item], seed: int, s: float = 1.0, kind: str = "full") -> list[Item]:
    """The same images with noise of ``kind`` at magnitude ``s``; each image's noise has its own seed."""
    return [
        (category, noise.apply(image, np.random.default_rng([seed, index]), s, kind), corners)
        for index, (category, image, corners) in enumerate(items)
    ]


def evaluate_set(detector: Detector, items: list[Item], progress: str | None = None) -> dict:
    """mAP and MLE over the pooled set, and per category: {"map", "mle", "per_category": {...}}."""
    by_category: dict[str, list] = {}
    for category, image, corners in progress_bar(items, desc=progress, disable=progress is None, leave=False):
        by_category.setdefault(category, []).append(match_detections(detector.detect(image), corners))
    pooled = merge([r for results in by_category.values() for r in results])
    per_category = {}
    for category, results in by_category.items():
        merged = merge(results)
        per_category[category] = {
            "ap": average_precision(merged),
            "mle": localization_error(merged),
            "false_positives_per_image": float((~merged.correct).sum() / len(results)),
        }
    return {"map": average_precision(pooled), "mle": localization_error(pooled), "per_category": per_category}


PAPER_TABLE = {  # the paper's Synthetic Shapes table: mAP clean, mAP noisy, MLE clean, MLE noisy
    "MagicPointL": (0.979, 0.971, 0.860, 1.012),
    "MagicPointS": (0.980, 0.939, 0.922, 1.078),
    "FAST": (0.405, 0.061, 1.656, 1.766),
    "Harris": (0.678, 0.213, 1.245, 1.409),
    "Shi": (0.686, 0.157, 1.188, 1.383),
}
SWEEP = (0.0, 0.25, 0.5, 0.75, 1.0, 1.25, 1.5, 1.75, 2.0)


def available_detectors(
    threshold: float = 0.001, border: int = 4, weights: tuple[Path, ...] = ()
) -> dict[str, Detector]:
    """FAST, Harris, Shi, every MagicPoint variant whose weights are shipped, MagicPoint S with four
    grid shifts (``MagicPointS-x4``) and S on the image enlarged 2x with two grid shifts, as the magic
    tracker runs it (``MagicPointS-2x``), and MagicPoint from each of ``weights`` (weights files or
    training checkpoints, named by their path; one pass, S-HA's own sub-pixel peaks); all drop
    detections within ``border`` pixels of the edge."""
    from deepslam.frontend.classical import ClassicalDetector
    from deepslam.frontend.magicpoint import VARIANTS, WEIGHTS, MagicPoint

    detectors: dict[str, Detector] = {
        f"MagicPoint{v}": MagicPoint.pretrained(v, threshold=threshold, border=border)
        for v in VARIANTS
        if (WEIGHTS / f"magicpoint_{v}.pt").exists()
    }
    detectors["MagicPointS-x4"] = MagicPoint.pretrained("S", threshold=threshold, border=border, grid_shifts=4)
    detectors["MagicPointS-2x"] = MagicPoint.pretrained(
        "S", threshold=threshold, border=border, grid_shifts=2, upsample=2
    )
    detectors.update({kind: ClassicalDetector(kind.lower(), border=border) for kind in ("FAST", "Harris", "Shi")})
    for path in weights:
        detectors[str(path)] = MagicPoint.pretrained("S-HA", path=path, threshold=threshold, border=border)
    return detectors


def _detector_figures(piece: tuple) -> dict:
    """Everything ``report`` measures of one detector: ``piece`` = (name, detector, per_category,
    sweep_per_category, seed)."""
    from deepslam.sim.shapes import evaluation_set

    name, detector, per_category, sweep_per_category, seed = piece
    items = evaluation_set(per_category, seed=seed)
    sweep_items = evaluation_set(sweep_per_category, seed=seed)
    clean_figures = evaluate_set(detector, items)
    noisy_figures = evaluate_set(detector, noisy_set(items, seed))
    sweep = {s: evaluate_set(detector, noisy_set(sweep_items, seed, s)) for s in SWEEP}
    kinds = {k: evaluate_set(detector, noisy_set(sweep_items, seed, 1.0, k)) for k in noise.KINDS}
    return {
        "clean": clean_figures,
        "noisy": noisy_figures,
        "sweep": {str(s): {"map": f["map"], "mle": f["mle"]} for s, f in sweep.items()},
        "noise_types": {k: {"map": f["map"], "mle": f["mle"]} for k, f in kinds.items()},
    }


def report(
    detectors: dict[str, Detector],
    per_category: int = DetectorEvalConfig.per_category,
    sweep_per_category: int = DetectorEvalConfig.sweep_per_category,
    seed: int = DetectorEvalConfig.seed,
    workers: Workers = Workers(),
) -> DetectorTable:
    """Everything ``deepslam eval detector`` shows: table, per category, noise sweep, noise types; the
    detectors run in parallel as ``workers`` says."""
    pieces = [(name, d, per_category, sweep_per_category, seed) for name, d in detectors.items()]
    figures = parallel_map(_detector_figures, pieces, workers, lambda p: f"detector {p[0]}", "detectors")
    return DetectorTable(per_category, seed, {name: f for name, f in zip(detectors, figures, strict=True)})


@dataclass
class DetectorTable(Result):
    """``deepslam eval detector``: per detector, mAP and MLE clean and noisy, per category, over the noise
    sweep and per noise type (``detectors``), on ``per_category_images`` images a category of ``seed``."""

    per_category_images: int
    seed: int
    detectors: dict[str, dict]
    name: ClassVar[str] = "detector"

    def lines(self) -> list[str]:
        return table_lines(self.to_dict()) + [""] + category_lines(self.to_dict())

    def plots(self, out: Path) -> list[Path]:
        return save_plots(self.to_dict(), out)


def table_lines(result: dict) -> list[str]:
    """The paper's table with this run's figures and the paper's beside them."""
    width = max(len("detector"), *map(len, result["detectors"]))
    lines = [
        f"{'detector':<{width}} {'mAP clean':>10} {'mAP noisy':>10} {'MLE clean':>10} {'MLE noisy':>10}"
        "   paper (same columns)"
    ]
    for name, figures in result["detectors"].items():
        ours = (figures["clean"]["map"], figures["noisy"]["map"], figures["clean"]["mle"], figures["noisy"]["mle"])
        paper = " / ".join(f"{v:.3f}" for v in PAPER_TABLE.get(name, ()))
        lines.append(f"{name:<{width}} " + " ".join(f"{v:>10.3f}" for v in ours) + f"   {paper}")
    return lines


def category_lines(result: dict) -> list[str]:
    names = list(result["detectors"])
    categories = list(next(iter(result["detectors"].values()))["clean"]["per_category"])
    lines = [f"{'AP clean/noisy':<16}" + "".join(f"{n:>16}" for n in names)]
    for category in categories:
        cells = [
            f"{d['clean']['per_category'][category]['ap']:.3f}/{d['noisy']['per_category'][category]['ap']:.3f}"
            for d in result["detectors"].values()
        ]
        lines.append(f"{category:<16}" + "".join(f"{c:>16}" for c in cells))
    return lines


def save_plots(result: dict, out_dir) -> list:
    """PNG plots: per-category AP, mAP/MLE against noise magnitude, mAP per noise type."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    detectors = result["detectors"]
    paths = []
    categories = list(next(iter(detectors.values()))["clean"]["per_category"])
    fig, axes = plt.subplots(1, 2, figsize=(13, 4), sharey=True)
    width = 0.8 / len(detectors)
    for ax, condition in zip(axes, ("clean", "noisy"), strict=False):
        for i, (name, figures) in enumerate(detectors.items()):
            ax.bar(
                np.arange(len(categories)) + i * width,
                [figures[condition]["per_category"][c]["ap"] for c in categories],
                width,
                label=name,
            )
        ax.set_xticks(np.arange(len(categories)) + 0.4 - width / 2, categories, rotation=45, ha="right")
        ax.set_title(f"AP per category ({condition})")
    axes[0].legend()
    fig.tight_layout()
    paths.append(out_dir / "detector_categories.png")
    fig.savefig(paths[-1], dpi=100)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for name, figures in detectors.items():
        s = [float(k) for k in figures["sweep"]]
        axes[0].plot(s, [v["map"] for v in figures["sweep"].values()], "o-", label=name)
        axes[1].plot(s, [v["mle"] for v in figures["sweep"].values()], "o-", label=name)
    axes[0].set(xlabel="noise magnitude s", ylabel="mAP", title="mAP vs noise magnitude")
    axes[1].set(xlabel="noise magnitude s", ylabel="MLE (px)", title="Localization error vs noise magnitude")
    axes[0].legend()
    fig.tight_layout()
    paths.append(out_dir / "detector_noise_magnitude.png")
    fig.savefig(paths[-1], dpi=100)
    fig, ax = plt.subplots(figsize=(10, 4))
    kinds = list(noise.KINDS)
    for i, (name, figures) in enumerate(detectors.items()):
        ax.bar(np.arange(len(kinds)) + i * width, [figures["noise_types"][k]["map"] for k in kinds], width, label=name)
    ax.set_xticks(np.arange(len(kinds)) + 0.4 - width / 2, kinds)
    ax.set(ylabel="mAP", title="mAP per noise type (s = 1)")
    ax.legend()
    fig.tight_layout()
    paths.append(out_dir / "detector_noise_types.png")
    fig.savefig(paths[-1], dpi=100)
    plt.close("all")
    return paths


PHOTOS = REAL_IMAGE_EVALUATION
PAPER_STATIC_R = {  # the paper's 30 Static Corners repeatability: (160x120 clean, noisy, 320x240 clean, noisy)
    "MagicPointL": (0.970, 0.811, 0.959, 0.765),
    "MagicPointS": (0.929, 0.711, 0.920, 0.675),
    "FAST": (0.800, 0.141, 0.812, 0.099),
    "Harris": (0.929, 0.136, 0.896, 0.081),
    "Shi": (0.852, 0.148, 0.827, 0.104),
}


def moved(image: np.ndarray, move: np.ndarray) -> np.ndarray:
    """``image`` (H, W) moved by the affine map ``move`` (3, 3) (bilinear, reflected borders), same size."""
    return cv2.warpAffine(image, move[:2], image.shape[::-1], flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT_101)


def _jittered(sequence: list[np.ndarray], rng: np.random.Generator, jitter_px: float) -> tuple[list, list]:
    """Each frame moved by its own random translation of up to ``jitter_px`` pixels in x and y (a
    hand-held camera; reflected borders); returns (frames, homographies (3, 3) from each frame to the next)."""
    shifts = rng.uniform(-jitter_px, jitter_px, (len(sequence), 2))
    moves = [np.array([[1.0, 0, dx], [0, 1, dy], [0, 0, 1]]) for dx, dy in shifts]
    frames = [moved(f, M) for f, M in zip(sequence, moves, strict=False)]
    return frames, [b @ np.linalg.inv(a) for a, b in zip(moves, moves[1:], strict=False)]


def photo_sequences(
    images: list[np.ndarray], frames: int, rng: np.random.Generator, noisy: bool, jitter_px: float
) -> list[tuple[list[np.ndarray], list[np.ndarray]]]:
    """For each image, ``frames`` frames of a camera under changing light (``sim.noise.relit_sequence``),
    with the full noise of ``sim.noise`` if ``noisy`` and moved by up to ``jitter_px`` pixels a frame;
    each sequence with its true homographies (3, 3) from each frame to the next."""
    sequences = []
    for image in images:
        sequence = noise.relit_sequence(image, frames, rng)
        sequence = [noise.apply(f, rng, 1.0) for f in sequence] if noisy else sequence
        still = (sequence, [np.eye(3)] * (len(sequence) - 1))
        sequences.append(_jittered(sequence, rng, jitter_px) if jitter_px > 0 else still)
    return sequences


def sequence_repeatability(
    detector: Detector, sequences: list[tuple[list[np.ndarray], list[np.ndarray]]], progress: str | None = None
) -> dict[str, float]:
    """{"repeatability", "n", "localization_error"}: frame-to-frame repeatability@N (eps = 2 px) over
    sequences of ``photo_sequences``, the mean detection count N where it peaks and the mean distance
    (pixels) between repeated points at that N."""
    from deepslam.frontend.evaluation.metrics import repeatability_at_n

    pairs = []
    for sequence, homographies in progress_bar(sequences, desc=progress, disable=progress is None, leave=False):
        points = [detector.detect(f) for f in sequence]
        pairs += list(zip(points[:-1], points[1:], homographies, strict=True))
    rep, count, error = repeatability_at_n(pairs, sequences[0][0][0].shape)
    return {"repeatability": rep, "n": count, "localization_error": error}


def _condition_figures(piece: tuple) -> dict:
    """Repeatability of one detector in one condition: ``piece`` = (name, detector, size, noisy, frames,
    seed, jitter_px); the condition's sequences come from its own seed, whichever detector runs on them."""
    name, detector, size, noisy, frames, seed, jitter_px = piece
    rng = np.random.default_rng([seed, size[0], int(noisy)])
    sequences = photo_sequences([photo(p, size) for p in PHOTOS], frames, rng, noisy, jitter_px)
    return sequence_repeatability(detector, sequences)


def static_repeatability(
    detectors: dict[str, Detector],
    frames: int = RealImagesConfig.frames,
    seed: int = RealImagesConfig.seed,
    sizes: tuple[tuple[int, int], ...] = ((120, 160), (240, 320)),
    jitter_px: float = RealImagesConfig.jitter,
    workers: Workers = Workers(),
) -> Repeatability:
    """Frame-to-frame repeatability@N (eps=2) on real photographs seen by a static camera under
    changing light, clean and with the full noise of ``sim.noise``; with ``jitter_px`` > 0 every frame
    is also translated by up to that many pixels (the true homographies are used)."""
    conditions = [(size, noisy) for size in sizes for noisy in (False, True)]
    pieces = [
        (name, d, size, noisy, frames, seed, jitter_px) for size, noisy in conditions for name, d in detectors.items()
    ]
    figures = parallel_map(
        _condition_figures, pieces, workers, lambda p: f"{p[0]} at {p[2]} noisy={p[3]}", "conditions"
    )
    result: dict = {}
    for (name, _, size, noisy, *_), figure in zip(pieces, figures, strict=True):
        result.setdefault(name, {})[f"{size[1]}x{size[0]} {'noisy' if noisy else 'clean'}"] = figure
    return Repeatability(result, jitter_px)


@dataclass
class Repeatability(Result):
    """``deepslam eval realimages``: per detector and condition (size, clean or noisy), repeatability@N, N
    and the localisation error of repeated points (``detectors``), the camera moving up to ``jitter_px`` a
    frame (files ``realimages``, or ``realimages_jitterPX``)."""

    detectors: dict[str, dict]
    jitter_px: float = 0.0

    @property
    def name(self) -> str:
        return f"realimages_jitter{self.jitter_px:g}" if self.jitter_px else "realimages"

    def to_dict(self) -> dict:
        return self.detectors

    def lines(self) -> list[str]:
        return static_lines(self.detectors)

    def plots(self, out: Path) -> list[Path]:
        return save_static_plots(self.detectors, out, self.name)


def static_lines(result: dict) -> list[str]:
    """Repeatability@N per detector and condition, with the paper's 30 Static Corners R beside it."""
    keys = list(next(iter(result.values())))
    width = max(26, *(len(name) + 1 for name in result))  # checkpoints are named by their path
    header = f"{'repeatability@N (loc. px)':<{width}}" + "".join(f"{k:>24}" for k in keys)
    lines = [header + "   paper R (same columns)"]
    for name, figures in result.items():
        paper = " / ".join(f"{v:.3f}" for v in PAPER_STATIC_R.get(name, ()))
        cells = [
            f"{figures[k]['repeatability']:>9.3f} @{figures[k]['n']:>4.0f} ({figures[k]['localization_error']:.2f})"
            for k in keys
        ]
        lines.append(f"{name:<{width}}" + "".join(f"{c:>24}" for c in cells) + f"   {paper}")
    return lines


def save_static_plots(result: dict, out_dir, name: str = "realimages") -> list:
    """PNG: repeatability@N and the localisation error of repeated points per detector and condition."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    detectors = list(result)
    conditions = list(result[detectors[0]])
    width = 0.8 / len(detectors)
    fig, axes = plt.subplots(1, 2, figsize=(13, 4))
    for i, detector in enumerate(detectors):
        x = np.arange(len(conditions)) + i * width
        axes[0].bar(x, [result[detector][c]["repeatability"] for c in conditions], width, label=detector)
        axes[1].bar(x, [result[detector][c]["localization_error"] for c in conditions], width, label=detector)
    for ax, title in zip(
        axes, ("repeatability@N (eps 2 px)", "localisation error of repeated points (px)"), strict=True
    ):
        ax.set_xticks(np.arange(len(conditions)) + 0.4 - width / 2, conditions)
        ax.set_title(title)
    axes[0].legend(fontsize=7, ncol=2)
    fig.tight_layout()
    path = out_dir / f"{name}.png"
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return [path]
