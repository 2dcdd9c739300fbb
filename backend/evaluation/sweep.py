"""Drift sweeps: simulated runs over worlds x trajectories x noise x lighting x front-ends, over seeds.

Each seed makes its own world (textures, layout). Runs on a corner-poor main texture (grass, gravel) are
summarised apart from those on photographs and Synthetic Shapes mosaics; a run fails when its ATE is
over ``FAILED_SHARE`` of its path length.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import ClassVar

import numpy as np

from deepslam.backend.config import OdometryConfig
from deepslam.backend.evaluation.config import SweepConfig
from deepslam.backend.evaluation.limit import over_limit
from deepslam.backend.evaluation.runs import simulate
from deepslam.errors import InputError
from deepslam.frontend.config import TrackerConfig
from deepslam.parallel import Workers, parallel_map
from deepslam.results import Result
from deepslam.sim.scenario import ScenarioConfig

FAILED_SHARE = 0.05


def _median(values: list[float]) -> float:
    return float(np.median(values)) if values else float("nan")


def run_cell(piece: tuple) -> dict:
    """One run of a sweep, ``piece`` = (cell, seed, config, tracker_config): its drift figures, texture and
    whether it failed."""
    cell, seed, config, tracker_config = piece
    world, path, noise, light, frontend = cell
    scenario = ScenarioConfig(
        world=world, trajectory=path, frames=config.frames, noise=noise, lighting=light, seed=seed
    )
    result = simulate(
        scenario,
        replace(tracker_config, frontend=frontend),
        OdometryConfig(scale=config.scale, method=config.method),
        progress=False,
        limit=True,
    )
    built = result["world"]
    figures = result["summary"]
    return {
        "seed": seed,
        "texture": built.texture,
        "corner_poor": built.corner_poor,
        "ate_se3": figures["ate_se3"],
        "path_length": figures["path_length"],
        "scale_drift": figures["scale_drift"],
        "failed": bool(figures["ate_se3"] > FAILED_SHARE * figures["path_length"]),
        "lost_frames": figures["lost_frames"],
        "track_error_px": figures["track_error_px"],
        "limit_ate_se3": figures.get("limit_ate_se3", float("nan")),
        "final_ate_se3": result["final_ate_se3"],
    }


def pipeline_matrix(
    config: SweepConfig = SweepConfig(),
    tracker_config: TrackerConfig = TrackerConfig(),
    progress: bool = True,
    workers: Workers = Workers(),
) -> Sweep:
    """One row per (world, trajectory, noise, lighting, front-end): the median ATE SE3 over seeds on
    photographs and mosaics and, apart, over corner-poor seeds; the failed runs; every run's figures."""
    cells, seeds = config.cells(), range(config.first_seed, config.first_seed + config.seeds)
    if config.worlds and config.trajectories and not config.paths():
        raise InputError(
            "a sweep has no forward path in the plane world (the camera would hit the wall): add the room or the "
            "clutter world, or another path"
        )
    if not cells:
        raise InputError("the sweep needs at least one world, trajectory, noise magnitude, lighting and front-end")
    pieces = [(cell, seed, config, tracker_config) for cell in cells for seed in seeds]
    results = parallel_map(run_cell, pieces, workers, _describe, "runs" if progress else None)
    return Sweep(
        [_row(cell, results[i * config.seeds : (i + 1) * config.seeds], config) for i, cell in enumerate(cells)]
    )


@dataclass
class Sweep(Result):
    """``deepslam eval pipeline``: a row per (world, trajectory, noise, lighting, front-end) with its
    medians, failures and every run (``matrix_lines``, ``save_plots``)."""

    rows: list[dict]
    name: ClassVar[str] = "pipeline"

    def lines(self) -> list[str]:
        return matrix_lines(self.rows)

    def plots(self, out: Path) -> list[Path]:
        return save_plots(self.to_dict(), out)


def _describe(piece: tuple) -> str:
    return " ".join(map(str, piece[0])) + f" seed {piece[1]}"


def _row(cell: tuple, runs: list[dict], config: SweepConfig) -> dict:
    """A sweep row: the cell, its medians (photographs and mosaics; corner-poor apart; the ATE also as % of
    the path and over the limit of the run's own tracks (``limit``), and |log scale drift|), failures, runs."""
    world, path, noise, light, frontend = cell
    textured = [r for r in runs if not r["corner_poor"]]
    shares = _shares(textured)
    return {
        "world": world, "trajectory": path, "noise": noise, "lighting": light, "frontend": frontend,
        "scale": config.scale,
        "median_ate_se3": _median([r["ate_se3"] for r in textured]),
        "median_ate_pct": _median(shares["ate_pct"]),
        "median_log_scale_drift": _median(shares["log_scale_drift"]),
        "median_ate_over_limit": _median(shares["ate_over_limit"]),
        "median_ate_se3_corner_poor": _median([r["ate_se3"] for r in runs if r["corner_poor"]]),
        "failed": sum(r["failed"] for r in runs),
        "runs": runs,
    }  # fmt: skip


def _shares(runs: list[dict]) -> dict[str, list[float]]:
    """Each run's ATE as % of its path, |log scale drift| and ATE over its limit (``limit``; of the runs that
    have one); the same of its final trajectory (``final_``; of the runs that record it)."""
    final = [r for r in runs if "final_ate_se3" in r]
    return {
        "ate_pct": [100 * r["ate_se3"] / r["path_length"] for r in runs],
        "log_scale_drift": [abs(np.log(r["scale_drift"])) for r in runs],
        "ate_over_limit": _over_limits(runs, "ate_se3"),
        "final_ate_pct": [100 * r["final_ate_se3"] / r["path_length"] for r in final],
        "final_over_limit": _over_limits(final, "final_ate_se3"),
    }


def _over_limits(runs: list[dict], key: str) -> list[float]:
    """Each run's ATE under ``key`` over its limit's, of the runs whose limit adjusted something (a finite ratio)."""
    ratios = (over_limit(r[key], r["limit_ate_se3"]) for r in runs)
    return [ratio for ratio in ratios if np.isfinite(ratio)]


def matrix_lines(rows: list[dict]) -> list[str]:
    """The sweep as a table, then every run's ATE with its seed's texture, then each front-end over all the cells
    (``summary_lines``). "/limit": the median ATE over that of the batch bundle adjustment of the run's own
    tracks, started at the truth (``limit``)."""
    lines = [
        f"{'world':<7} {'path':<8} {'noise':>5} {'light':>5} {'frontend':<9} {'ATE med m':>9} {'% path':>6} "
        f"{'|log s|':>7} {'/limit':>6} {'corner-poor':>11} {'failed':>7}"
    ]
    for r in rows:
        lines.append(
            f"{r['world']:<7} {r['trajectory']:<8} {r['noise']:>5.2f} {r['lighting']:>5.2f} {r['frontend']:<9} "
            f"{r['median_ate_se3']:>9.4f} {r.get('median_ate_pct', np.nan):>6.2f} "
            f"{r.get('median_log_scale_drift', np.nan):>7.3f} {r.get('median_ate_over_limit', np.nan):>6.2f} "
            f"{r['median_ate_se3_corner_poor']:>11.4f} "
            f"{r['failed']:>3}/{len(r['runs']):<3}"
        )
    textures = ", ".join(f"{run['seed']} {run['texture']}" for run in rows[0]["runs"])
    lines += ["", f"ATE SE3 m per seed (seed texture: {textures}):"]
    lines += [
        f"{r['world']:<7} {r['trajectory']:<8} {r['noise']:>5.2f} {r['lighting']:>5.2f} {r['frontend']:<9} "
        + " ".join(f"{run['ate_se3']:7.4f}" for run in r["runs"])
        for r in rows
    ]
    return lines + ["", *summary_lines(rows)]


def summary_lines(rows: list[dict]) -> list[str]:
    """Each front-end at each noise and lighting over all the sweep's worlds, paths and seeds: the runs on
    photographs and mosaics, their median and mean ATE as % of the path, their median ATE over the limit, the
    median of their final trajectories' ATE (the graph's, refined by later frames: ``Pipeline.trajectory``) as %
    of the path and over the limit, their median |log scale drift|, and the lost frames of all its runs."""
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault((r["frontend"], r["noise"], r["lighting"]), []).extend(r["runs"])
    lines = [
        "Over all worlds, paths and seeds (photographs and mosaics; lost frames of every run):",
        f"{'frontend':<9} {'noise':>5} {'light':>5} {'runs':>4} {'med %':>6} {'mean %':>6} {'/limit':>6} "
        f"{'final %':>7} {'/limit':>6} {'|log s|':>7} {'lost':>5}",
    ]
    for (frontend, noise, light), runs in sorted(groups.items()):
        textured = [r for r in runs if not r["corner_poor"]]
        shares = _shares(textured)
        pct = shares["ate_pct"]
        lines.append(
            f"{frontend:<9} {noise:>5.2f} {light:>5.2f} {len(textured):>4} {_median(pct):>6.2f} "
            f"{np.mean(pct) if pct else np.nan:>6.2f} {_median(shares['ate_over_limit']):>6.2f} "
            f"{_median(shares['final_ate_pct']):>7.2f} {_median(shares['final_over_limit']):>6.2f} "
            f"{_median(shares['log_scale_drift']):>7.3f} {sum(r['lost_frames'] for r in runs):>5}"
        )
    return lines


def save_plots(result: dict, out_dir) -> list:
    """PNG: median ATE (photographs and mosaics) against noise, per front-end, one panel per world and
    trajectory, lighting 0 solid and others dashed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = result["rows"]
    panels = sorted({(r["world"], r["trajectory"]) for r in rows})
    fig, axes = plt.subplots(1, len(panels), figsize=(4 * len(panels), 3.6), squeeze=False, sharey=True)
    colours = {name: f"C{i}" for i, name in enumerate(sorted({r["frontend"] for r in rows}))}
    for ax, (world, path) in zip(axes[0], panels, strict=True):
        for (frontend, light), group in _groups(rows, world, path).items():
            noise = [r["noise"] for r in group]
            style = "-" if light == 0 else "--"
            ax.plot(noise, [r["median_ate_se3"] for r in group], style, marker="o", color=colours[frontend],
                    label=f"{frontend}" + (f" light {light:g}" if light else ""))  # fmt: skip
        ax.set(title=f"{world}, {path}", xlabel="noise magnitude s", yscale="log")
    axes[0][0].set_ylabel("median ATE SE3 (m)")
    axes[0][-1].legend(fontsize=7)
    fig.tight_layout()
    path = out_dir / "pipeline_ate_vs_noise.png"
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return [path]


def _groups(rows: list[dict], world: str, path: str) -> dict[tuple, list[dict]]:
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        if r["world"] == world and r["trajectory"] == path:
            groups.setdefault((r["frontend"], r["lighting"]), []).append(r)
    return {key: sorted(group, key=lambda r: r["noise"]) for key, group in groups.items()}
