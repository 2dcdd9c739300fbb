"""Forward-pass timings on one CPU thread, BatchNorm folded, after warm-up (the paper's set-up)."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from deepslam.errors import InputError
from deepslam.frontend.config import BENCH_REPEATS, EXTRACTION_PRESETS
from deepslam.results import Result

PAPER_MS = {
    ("S", (120, 160)): 5.3,
    ("S", (240, 320)): 38.1,
    ("L", (120, 160)): 19.4,
    ("L", (240, 320)): 150.9,
    ("warp", (120, 160)): 2.3,
    ("warp", (240, 320)): 6.1,
}


def time_ms(fn: Callable[[], object], repeats: int = 100, warmup: int = 10) -> float:
    """Median wall time of ``fn`` in milliseconds."""
    if repeats < 1 or warmup < 0:
        raise InputError(f"timing needs at least 1 repetition and no negative warm-up, got {repeats} and {warmup}")
    for _ in range(warmup):
        fn()
    samples = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        samples.append(time.perf_counter() - start)
    return 1e3 * float(np.median(samples))


PAPER_EXTRACTION = tuple(getattr(EXTRACTION_PRESETS["default"], k) for k in ("threshold", "nms_radius", "border"))


def bench_detector(repeats: int = BENCH_REPEATS) -> NetworkTimings:
    """MagicPoint S and L forward passes and point extraction at 160x120 and 320x240."""
    from deepslam.frontend.magicpoint import VARIANTS, WEIGHTS, MagicPoint, MagicPointNet
    from deepslam.frontend.points import extract_points
    from deepslam.sim.shapes import render

    torch.set_num_threads(1)
    rows = []
    image, _ = render("checkerboards", np.random.default_rng(0), (240, 320))
    for variant in VARIANTS:
        shipped = (WEIGHTS / f"magicpoint_{variant}.pt").exists()
        model = MagicPoint.pretrained(variant) if shipped else MagicPoint(MagicPointNet(VARIANTS[variant]))
        for size in ((120, 160), (240, 320)):
            x = torch.rand(1, 1, *size)
            with torch.inference_mode():
                count = repeats if variant == "S" else max(10, repeats // 5)
                forward = time_ms(lambda x=x, model=model: model.net(x), count)
            heatmap = model.heatmap(np.ascontiguousarray(image[: size[0], : size[1]]))
            extraction = time_ms(lambda heatmap=heatmap: extract_points(heatmap, *PAPER_EXTRACTION), repeats)
            rows.append(
                {
                    "model": f"MagicPoint{variant}",
                    "size": f"{size[1]}x{size[0]}",
                    "forward_ms": forward,
                    "extract_ms": extraction,
                    "paper_ms": PAPER_MS.get((variant, size), float("nan")),
                    "weights": "shipped" if shipped else "untrained",
                }
            )
    return NetworkTimings(rows, "detector")


def bench_warp(repeats: int = BENCH_REPEATS) -> NetworkTimings:
    """MagicWarp forward passes on 20x15x130 and 40x30x130 inputs (the shipped network, or the default
    architecture untrained when no weights are shipped)."""
    from deepslam.frontend.magicwarp import WEIGHTS, MagicWarp, MagicWarpNet

    torch.set_num_threads(1)
    shipped = (WEIGHTS / "magicwarp.pt").exists()
    warp = MagicWarp.pretrained() if shipped else MagicWarp(MagicWarpNet())
    rows = []
    for size in ((120, 160), (240, 320)):
        x = torch.rand(1, 130, size[0] // 8, size[1] // 8)
        with torch.inference_mode():
            forward = time_ms(lambda x=x: warp.net(x), repeats)
        rows.append(
            {
                "model": "MagicWarp",
                "input": f"{size[1] // 8}x{size[0] // 8}x130",
                "forward_ms": forward,
                "paper_ms": PAPER_MS[("warp", size)],
                "weights": "shipped" if shipped else "untrained",
            }
        )
    return NetworkTimings(rows, "warp")


@dataclass
class NetworkTimings(Result):
    """``deepslam bench detector`` or ``bench warp``: a row per network and input size (median forward pass
    in ms, point extraction for MagicPoint, the paper's time, shipped or untrained weights)."""

    rows: list[dict]
    network: str  # "detector" or "warp"

    @property
    def name(self) -> str:
        return f"bench_{self.network}"

    def to_dict(self) -> dict:
        return {"rows": self.rows}

    def lines(self) -> list[str]:
        def cell(key, value):
            return f"{key}={value:.2f}" if isinstance(value, float) else f"{key}={value}"

        return ["  " + "  ".join(cell(k, v) for k, v in row.items()) for row in self.rows]

    def plots(self, out: Path) -> list[Path]:
        return save_plots(self.rows, out, self.name)


def save_plots(rows: list[dict], out_dir, name: str) -> list:
    """PNG: each model's forward pass (and point extraction) beside the paper's time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labels = [f"{r['model']} {r.get('size', r.get('input', ''))}" for r in rows]
    x = np.arange(len(rows))
    fig, ax = plt.subplots(figsize=(max(6, 1.3 * len(rows)), 3.6))
    ax.bar(x - 0.2, [r["forward_ms"] for r in rows], 0.4, label="forward (here)")
    ax.bar(x + 0.2, [r["paper_ms"] for r in rows], 0.4, label="paper")
    ax.set_xticks(x, labels, rotation=20, ha="right", fontsize=8)
    ax.set(ylabel="ms, one thread", yscale="log", title="forward pass")
    ax.legend()
    fig.tight_layout()
    path = out_dir / f"{name}.png"
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return [path]
