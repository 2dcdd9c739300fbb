"""MagicWarp evaluation: match repeatability and the paper's 90% breakdown-point table."""

from __future__ import annotations

import dataclasses
import textwrap
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np

from deepslam.frontend.evaluation.config import WarpEvalConfig
from deepslam.frontend.magicwarp import MagicWarp, MagicWarpNet, refine
from deepslam.geometry import warp_points
from deepslam.parallel import Workers, parallel_map
from deepslam.results import Result
from deepslam.sim.homography import image_corners
from deepslam.sim.pointsets import MOTIONS, PointSetPair, make_pair, motion_homography, random_direction

SIZE = (120, 160)


def match_repeatability(H: np.ndarray, pair: PointSetPair) -> float:
    """Percentage of A points (with a partner in B) whose nearest B point after warping by ``H`` is
    their true partner (the paper's MatchRep)."""
    has_partner = pair.true_index >= 0
    if not has_partner.any():
        return 100.0
    if len(pair.points_b) == 0:
        return 0.0
    moved = warp_points(pair.points_a[has_partner], H)
    nearest = np.argmin(np.linalg.norm(moved[:, None] - pair.points_b[None], axis=2), axis=1)
    return 100.0 * float(np.mean(nearest == pair.true_index[has_partner]))


DENSITIES = {"low": (5, 25), "medium": (25, 50), "high": (100, 200)}
EXTRAS = (0.0, 0.2, 0.4)
GRIDS = {
    "translation": np.arange(0, 61, 1.0),
    "rotation": np.arange(0, 61, 1.0),
    "scale": np.round(np.arange(1.0, 1.601, 0.01), 2),
    "random_h": np.arange(0, 61, 1.0),
}
UNITS = {"translation": "px", "rotation": "deg", "scale": "x", "random_h": "px"}
PAPER = {  # (density, extra) -> NN (trans, rot, scale, randH), MagicWarp (trans, rot, scale, randH)
    ("low", 0.0): ((8.41, 9.42, 1.20, 13.89), (24.00, 21.45, 1.32, 32.83)),
    ("low", 0.2): ((9.05, 8.87, 1.24, 11.76), (24.06, 21.25, 1.31, 29.78)),
    ("low", 0.4): ((7.15, 7.70, 1.20, 11.59), (22.64, 19.65, 1.20, 28.84)),
    ("medium", 0.0): ((5.19, 5.93, 1.11, 8.03), (20.20, 20.01, 1.23, 26.52)),
    ("medium", 0.2): ((4.82, 5.41, 1.11, 7.68), (18.29, 18.07, 1.21, 24.84)),
    ("medium", 0.4): ((4.66, 4.50, 1.10, 6.56), (17.08, 18.03, 1.19, 24.47)),
    ("high", 0.0): ((3.49, 3.49, 1.07, 4.87), (15.10, 15.38, 1.17, 17.51)),
    ("high", 0.2): ((3.39, 3.34, 1.06, 4.72), (12.97, 13.97, 1.13, 15.35)),
    ("high", 0.4): ((3.27, 3.13, 1.06, 4.26), (10.92, 11.17, 1.10, 12.13)),
}


def validation_set(seed: int, runs: int = 24) -> list[tuple[str, PointSetPair]]:
    """Training validation at the target: for every cell of the breakdown table (density, extra points,
    motion), ``runs`` pairs moved by the paper's MagicWarp breakdown magnitude of that cell; (motion, pair)."""
    rng = np.random.default_rng(seed)
    validation = []
    for (density, extra), (_, paper) in PAPER.items():
        fewest, most = DENSITIES[density]
        for motion, magnitude in zip(MOTIONS, paper, strict=False):
            for _ in range(runs):
                H = motion_homography(motion, magnitude, SIZE, random_direction(rng))
                validation.append((motion, make_pair(rng, H, int(rng.integers(fewest, most + 1)), extra, SIZE)))
    return validation


def validation_figures(net: MagicWarpNet, validation: list[tuple[str, PointSetPair]]) -> dict[str, float]:
    """Mean match repeatability per motion at the paper's breakdown magnitudes ("rep@paper:rotation", ...),
    the percentage of pairs still at 90% or more there ("pass@paper"), and the mean repeatability over all
    pairs as "score". Unlike repeatability at fixed magnitudes of one density, it ranks checkpoints as the
    breakdown table's shortfall from the paper does (frontend/weights/magicwarp.md)."""
    warp = MagicWarp(net)
    H = warp.estimate_batch([(p.points_a, p.points_b) for _, p in validation], SIZE)
    reps = np.array([match_repeatability(h, pair) for h, (_, pair) in zip(H, validation, strict=False)])
    motions = np.array([motion for motion, _ in validation])
    figures = {f"rep@paper:{m}": float(reps[motions == m].mean()) for m in MOTIONS if (motions == m).any()}
    return figures | {"pass@paper": float(100 * np.mean(reps >= 90.0)), "score": float(reps.mean())}


def ransac_reference(pair: PointSetPair) -> np.ndarray:
    """The classical reference: a robust homography (OpenCV's USAC MAGSAC, 3 px) fitted to
    nearest-neighbour guesses (identity if it fails)."""
    import cv2

    if len(pair.points_a) < 4 or len(pair.points_b) < 4:
        return np.eye(3)
    nearest = np.argmin(np.linalg.norm(pair.points_a[:, None] - pair.points_b[None], axis=2), axis=1)
    H, _ = cv2.findHomography(pair.points_a, pair.points_b[nearest], cv2.USAC_MAGSAC, 3.0)
    return np.eye(3) if H is None else H / H[2, 2]


def _breakdown(magnitudes: np.ndarray, reps: np.ndarray, threshold: float = 90.0) -> float:
    """First magnitude where repeatability drops below ``threshold``, linearly interpolated."""
    below = np.nonzero(reps < threshold)[0]
    if len(below) == 0:
        return float(magnitudes[-1])
    i = below[0]
    if i == 0:
        return float(magnitudes[0])
    fraction = (reps[i - 1] - threshold) / max(reps[i - 1] - reps[i], 1e-9)
    return float(magnitudes[i - 1] + fraction * (magnitudes[i] - magnitudes[i - 1]))


def _cell_repeatability(piece: tuple) -> dict[str, np.ndarray]:
    """Match repeatability (runs, magnitudes) of every method in one cell (density, extra, motion)."""
    warp, density, extra, motion, runs, seed, methods = piece
    grid = GRIDS[motion]
    reps = {method: np.zeros((runs, len(grid))) for method in methods}
    for run in range(runs):
        rng = np.random.default_rng([seed, run])
        count = int(rng.integers(DENSITIES[density][0], DENSITIES[density][1] + 1))
        direction = random_direction(rng)
        pairs = [
            make_pair(np.random.default_rng([seed, run, 1]), motion_homography(motion, m, SIZE, direction), count,
                      extra, SIZE)
            for m in grid
        ]  # fmt: skip
        estimates = {"nearest_neighbour": [np.eye(3)] * len(pairs), "ransac": [ransac_reference(p) for p in pairs]}
        if warp:
            inputs = [(p.points_a, p.points_b) for p in pairs]
            first = warp.estimate_batch(inputs, SIZE)
            estimates["magicwarp"] = list(first)
            second = warp.estimate_batch(
                [(warp_points(a, H), b) for (a, b), H in zip(inputs, first, strict=True)], SIZE
            )
            estimates["magicwarp_x2"] = [h2 @ h1 / (h2 @ h1)[2, 2] for h1, h2 in zip(first, second, strict=True)]
            estimates["magicwarp_refined"] = [refine(a, b, H) for (a, b), H in zip(inputs, first, strict=True)]
            estimates["magicwarp_clean_b"] = list(
                warp.estimate_batch([(p.points_a, p.without_spurious().points_b) for p in pairs], SIZE)
            )
        for method in methods:
            reps[method][run] = [match_repeatability(H, p) for H, p in zip(estimates[method], pairs, strict=True)]
    return reps


def breakdown_table(
    warp: MagicWarp | None,
    runs: int = WarpEvalConfig.runs,
    seed: int = WarpEvalConfig.seed,
    progress: bool = True,
    workers: Workers = Workers(),
) -> WarpBreakdown:
    """The paper's 90% breakdown table for NN, RANSAC, MagicWarp, MagicWarp x2, MagicWarp refined by
    snapping and a robust fit (``frontend.magicwarp.refine``), and MagicWarp given image B without its
    spurious points but scored with them, "magicwarp_clean_b": how far a network that ignored spurious
    points would reach (the last four if ``warp``).

    Returns a ``WarpBreakdown``.
    """

    methods = ["nearest_neighbour", "ransac"] + (
        ["magicwarp", "magicwarp_x2", "magicwarp_refined", "magicwarp_clean_b"] if warp else []
    )
    table: dict = {}
    curves: dict = {}
    jobs = [(d, e, m) for d in DENSITIES for e in EXTRAS for m in GRIDS]
    pieces = [(warp, d, e, m, runs, seed, methods) for d, e, m in jobs]
    results = parallel_map(_cell_repeatability, pieces, workers, lambda p: f"cell {p[1]} {p[2]} {p[3]}",
                           "breakdown" if progress else None)  # fmt: skip
    for (density, extra, motion), reps in zip(jobs, results, strict=True):
        grid = GRIDS[motion]
        table.setdefault(density, {}).setdefault(str(extra), {})
        for method in methods:
            value = float(np.mean([_breakdown(grid, r) for r in reps[method]]))
            table[density][str(extra)].setdefault(method, {})[motion] = value
        if density == "medium" and extra == 0.2:
            curves[motion] = {method: reps[method].mean(0).tolist() for method in methods}
    grids = {m: g.tolist() for m, g in GRIDS.items()}
    return WarpBreakdown(table, curves, grids, runs, motion_errors(warp, runs, seed) if warp else None)


@dataclass
class WarpBreakdown(Result):
    """``deepslam eval warp``: the 90% breakdown point of every method ({density: {extra: {method: {motion:
    magnitude}}}}), match repeatability against magnitude at medium density and 20% extra points
    (``curves``, on ``grids``), ``runs`` point sets a cell, and MagicWarp's errors per motion (or None)."""

    breakdown: dict
    curves: dict
    grids: dict
    runs: int
    motion_errors: dict | None = None
    name: ClassVar[str] = "warp"

    def to_dict(self) -> dict:
        figures = dataclasses.asdict(self)
        return figures if self.motion_errors is not None else {k: v for k, v in figures.items() if k != "motion_errors"}

    def lines(self) -> list[str]:
        return table_lines(self.to_dict())

    def plots(self, out: Path) -> list[Path]:
        return save_plots(self.to_dict(), out)


ERROR_MAGNITUDES = {
    "translation": (5.0, 10.0, 20.0),
    "rotation": (5.0, 10.0, 20.0),
    "scale": (1.05, 1.1, 1.2),
    "random_h": (5.0, 10.0, 20.0),
}


def motion_errors(warp: MagicWarp, runs: int = 50, seed: int = 0) -> dict:
    """How much of each motion the raw network recovers, at medium density with 20% extra points:
    {motion: [{"magnitude", "corner_shift_px": mean displacement of the image corners under the true
    motion, "corner_error_px": median over runs of the mean corner distance between H and the truth}]}."""
    corners = image_corners(SIZE)

    def corner_gap(H_1: np.ndarray, H_2: np.ndarray) -> float:
        return float(np.linalg.norm(warp_points(corners, H_1) - warp_points(corners, H_2), axis=1).mean())

    result: dict = {}
    for motion, magnitudes in ERROR_MAGNITUDES.items():
        for magnitude in magnitudes:
            rng = np.random.default_rng([seed, 7])  # the same directions and point sets at every magnitude
            truths = [motion_homography(motion, magnitude, SIZE, random_direction(rng)) for _ in range(runs)]
            pairs = [make_pair(rng, H, int(rng.integers(25, 51)), 0.2, SIZE) for H in truths]
            estimates = warp.estimate_batch([(p.points_a, p.points_b) for p in pairs], SIZE)
            result.setdefault(motion, []).append(
                {
                    "magnitude": magnitude,
                    "corner_shift_px": float(np.mean([corner_gap(H, np.eye(3)) for H in truths])),
                    "corner_error_px": float(
                        np.median([corner_gap(E, H) for E, H in zip(estimates, truths, strict=False)])
                    ),
                }
            )
    return result


def error_lines(errors: dict) -> list[str]:
    lines = ["raw MagicWarp, medium density, 20% extra: median corner error px / true corner shift px"]
    for motion, rows in errors.items():
        cells = "   ".join(
            f"{r['magnitude']:g}{UNITS[motion]}: {r['corner_error_px']:5.2f} / {r['corner_shift_px']:5.2f}"
            for r in rows
        )
        lines.append(f"  {motion:<12}{cells}")
    return lines


def short_of_paper(result: dict, method: str) -> list[str]:
    """The breakdown cells where ``method`` (a MagicWarp row) falls below the paper's MagicWarp column,
    compared at the table's two decimals, as "density extra% motion value<paper"."""
    short = []
    for (density, extra), (_, paper) in PAPER.items():
        figures = result["breakdown"][density][str(extra)][method]
        short += [
            f"{density} {extra:.0%} {motion} {figures[motion]:.2f}<{target:.2f}"
            for motion, target in zip(GRIDS, paper, strict=False)
            if round(figures[motion], 2) < target
        ]
    return short


def table_lines(result: dict) -> list[str]:
    methods = list(next(iter(next(iter(result["breakdown"].values())).values())))
    lines = []
    for method in methods:
        lines.append(
            f"{method}: trans px / rot deg / scale x / randH px"
            + (
                "   [paper NN]"
                if method == "nearest_neighbour"
                else "   [paper MagicWarp]"
                if method.startswith("magicwarp")
                else ""
            )
        )
        for density, extras in result["breakdown"].items():
            for extra, figures in extras.items():
                values = " ".join(f"{figures[method][m]:>7.2f}" for m in GRIDS)
                paper = PAPER[(density, float(extra))][0 if method == "nearest_neighbour" else 1]
                note = "   [" + " ".join(f"{v:.2f}" for v in paper) + "]" if method != "ransac" else ""
                lines.append(f"  {density:<7}{float(extra):>4.0%} {values}{note}")
        if method.startswith("magicwarp"):
            short, cells = short_of_paper(result, method), len(PAPER) * len(GRIDS)
            summary = f"{cells - len(short)} of {cells} cells at or above the paper"
            lines += textwrap.wrap(
                summary + (f"; short: {', '.join(short)}" if short else ""),
                110,
                initial_indent="  ",
                subsequent_indent="    ",
            )
    return lines + ([""] + error_lines(result["motion_errors"]) if "motion_errors" in result else [])


def save_plots(result: dict, out_dir) -> list:
    """Match repeatability against magnitude for the four motions (medium density, 20% extra points)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 4, figsize=(18, 4))
    for ax, (motion, curves) in zip(axes, result["curves"].items(), strict=False):
        grid = result["grids"][motion]
        for method, values in curves.items():
            ax.plot(grid, values, label=method)
            breakdown = result["breakdown"]["medium"]["0.2"][method][motion]
            ax.axvline(breakdown, ls="--", lw=0.8, color=ax.lines[-1].get_color())
        ax.axhline(90, color="grey", lw=0.5)
        ax.set(
            title=f"{motion} (medium density, 20% extra)",
            xlabel=UNITS[motion],
            ylabel="match repeatability (%)",
            ylim=(0, 101),
        )
    axes[0].legend()
    fig.tight_layout()
    path = out_dir / "warp_breakdown.png"
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return [path]
