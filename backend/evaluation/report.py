"""`deepslam report`: one self-contained HTML page comparing runs from their logs alone.

Per run: its settings, drift figures (where the log has ground truth), a top view of the estimate and
the truth, translation error and RPE over time, tracks and inliers per frame with keyframes and lost
frames marked, the map's size and the scale over time (estimated over true path length), and a strip of
frames with their tracks drawn. Images are embedded (base64 PNG): the page
needs no network. What a log lacks (ground truth, diagnostics) or lost (a cut-off file) is said on the page.
"""

from __future__ import annotations

import base64
import html
import io
import json
import warnings
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import cv2
import numpy as np

from deepslam.backend import drift
from deepslam.files import distinct_names, written
from deepslam.logs.frames import LogFrame
from deepslam.logs.reader import LogError, read_frames, read_metadata

STRIP_FRAMES = 6  # frames shown per run, evenly spaced
SCALE_WINDOW = 10  # frames over which the scale plot compares the estimated path length with the true one


@dataclass
class Run:
    """What a log holds for the report."""

    path: Path
    frames: list[LogFrame]
    metadata: dict
    notes: list[str] = field(default_factory=list)  # what is missing or was lost
    lost: list[str] = field(default_factory=list)  # what reading the file lost (a cut-off or damaged log)
    name: str = ""  # what to show it by, where its file name is not enough (``distinct_names``)

    @property
    def label(self) -> str:
        return str(Path(self.name).with_suffix("")) if self.name else self.path.stem

    @cached_property
    def poses(self) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """(seconds (N,), truth (N, 4, 4), estimate (N, 4, 4)) of the frames with both, or None."""
        both = [f for f in self.frames if f.T_groundtruth is not None and f.T_estimate is not None]
        if len(both) < 2:
            return None
        seconds = np.array([(f.stamp_ns - both[0].stamp_ns) / 1e9 for f in both])
        return seconds, np.stack([f.T_groundtruth for f in both]), np.stack([f.T_estimate for f in both])

    @cached_property
    def estimates(self) -> np.ndarray | None:
        """The estimated poses (N, 4, 4) of the frames that have one, or None for fewer than two."""
        poses = [f.T_estimate for f in self.frames if f.T_estimate is not None]
        return np.stack(poses) if len(poses) >= 2 else None


def load_run(path: Path) -> Run:
    """A log as a ``Run``; LogError if nothing of it can be read as a deepslam log."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        frames = list(read_frames(path))
    lost = [str(w.message) for w in caught]
    try:
        metadata = read_metadata(path)
    except LogError as error:
        metadata, lost = {}, [*lost, str(error)]
    run = Run(path, frames, metadata, list(lost), lost)
    if run.poses is None:
        run.notes.append("no ground truth (/groundtruth/pose): drift figures are not available; the estimate is drawn")
    if not any(f.diagnostics for f in frames):
        run.notes.append("no per-frame diagnostics (/diagnostics/frame): written by deepslam 0.2.0 and later")
    return run


def _png(fig) -> str:
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=90)
    return base64.b64encode(buffer.getvalue()).decode()


def _image_tag(png_base64: str, alt: str) -> str:
    return f'<img alt="{html.escape(alt)}" src="data:image/png;base64,{png_base64}">'


def trajectory_figures(runs: list[Run]) -> str:
    """Top views of the runs' estimates: aligned to their truth and drawn with it where the log has truth, the
    others as they are on axes of their own (their units need not be metres); translation error (after SE(3)
    alignment) and RPE over time for the runs with truth. Legends sit below the plots."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with_truth = [(run, run.poses) for run in runs if run.poses is not None]
    estimates = [(run, run.estimates) for run in runs if run.poses is None and run.estimates is not None]
    if not with_truth and not estimates:
        return "<p>No run has estimated poses: no trajectory plots.</p>"
    panels = 3 * bool(with_truth) + bool(estimates)
    fig, axes = plt.subplots(1, panels, figsize=(5 * panels, 5.2), squeeze=False)
    axes = list(axes[0])
    if with_truth:
        _truth_panels(axes[:3], with_truth)
    if estimates:
        _own_units_panel(axes[-1], estimates)
    for ax in axes:
        _legend_below(ax)
    fig.tight_layout()
    tag = _image_tag(_png(fig), "trajectories")
    plt.close(fig)
    return tag


def _truth_panels(axes: list, with_truth: list[tuple[Run, tuple]]) -> None:
    """Top view (aligned, SE(3)), translation error and RPE over time of runs with truth, on three ``axes``."""
    for run, (seconds, truth, estimate) in with_truth:
        shown = np.sort(np.argsort(truth[:, :3, 3].std(0))[1:])  # the two axes with the most motion
        aligned = drift.align(estimate, truth, with_scale=False)
        line = axes[0].plot(aligned[:, shown[0], 3], aligned[:, shown[1], 3], label=f"{run.label} estimate")[0]
        axes[0].plot(truth[:, shown[0], 3], truth[:, shown[1], 3], "--", color=line.get_color(), alpha=0.6,
                     label=f"{run.label} truth")  # fmt: skip
        axes[1].plot(seconds, np.linalg.norm(aligned[:, :3, 3] - truth[:, :3, 3], axis=1), label=run.label)
        axes[2].plot(seconds[1:], drift.rpe(estimate, truth)[0], label=run.label)
    axes[0].set(title="top view, aligned to the truth (SE(3))", xlabel="m", ylabel="m")
    axes[0].axis("equal")
    axes[1].set(title="translation error over time (ATE)", xlabel="time (s)", ylabel="m")
    axes[2].set(title="RPE over time (1 frame)", xlabel="time (s)", ylabel="m")


def _own_units_panel(ax, estimates: list[tuple[Run, np.ndarray]]) -> None:
    """Top view of runs without truth, each estimate as it is, in the run's own units."""
    for run, estimate in estimates:
        shown = np.sort(np.argsort(estimate[:, :3, 3].std(0))[1:])
        ax.plot(estimate[:, shown[0], 3], estimate[:, shown[1], 3], label=f"{run.label} estimate")
    ax.set(title="top view, no truth (the runs' own units)", xlabel="run units", ylabel="run units")
    ax.axis("equal")


def _legend_below(ax) -> None:
    """The legend of ``ax`` under it, outside the plot (none for an axes without labelled lines)."""
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.2), ncol=2, frameon=False)


def tracking_figure(runs: list[Run]) -> str:
    """Tracks and inliers per frame; keyframes as ticks at the bottom, lost frames as red crosses."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(runs), figsize=(5 * len(runs), 3.4), squeeze=False, sharey=True)
    for ax, run in zip(axes[0], runs, strict=True):
        index = np.arange(len(run.frames))
        tracks = [len(f.tracks) if f.tracks is not None else 0 for f in run.frames]
        ax.plot(index, tracks, label="tracks")
        diagnostics = [f.diagnostics for f in run.frames]
        if all(d is not None for d in diagnostics) and diagnostics:
            ax.plot(index, [d.inliers for d in diagnostics], label="inliers")
            keyframes = [i for i, d in enumerate(diagnostics) if d.keyframe]
            lost = [i for i, d in enumerate(diagnostics) if d.lost]
            ax.plot(keyframes, np.zeros(len(keyframes)), "k|", markersize=12, label="keyframes")
            ax.plot(lost, np.zeros(len(lost)), "rx", markersize=8, label=f"lost ({len(lost)})")
        ax.set(title=run.label, xlabel="frame")
        _legend_below(ax)
    axes[0][0].set_ylabel("points")
    fig.tight_layout()
    tag = _image_tag(_png(fig), "tracks and inliers")
    plt.close(fig)
    return tag


def map_figure(runs: list[Run]) -> str:
    """The map's landmarks per frame (runs with a map) and the scale over time: the estimate's path length over
    the truth's across ``SCALE_WINDOW`` frames (runs with truth; 1 is metric, its drift is scale drift)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    mapped = [run for run in runs if any(f.diagnostics is not None and f.diagnostics.landmarks for f in run.frames)]
    scaled = [run for run in runs if run.poses is not None and len(run.poses[0]) > SCALE_WINDOW]
    if not mapped and not scaled:
        return "<p>No run has a map or ground truth: no map plots.</p>"
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.4), squeeze=False)
    for run in mapped:
        axes[0][0].plot([f.diagnostics.landmarks if f.diagnostics else 0 for f in run.frames], label=run.label)
    for run in scaled:
        seconds, truth, estimate = run.poses
        steps = [np.linalg.norm(np.diff(p[:, :3, 3], axis=0), axis=1) for p in (estimate, truth)]
        window = np.ones(SCALE_WINDOW)
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.convolve(steps[0], window, "valid") / np.convolve(steps[1], window, "valid")
        axes[0][1].plot(seconds[SCALE_WINDOW:], ratio, label=run.label)
    axes[0][0].set(title="map size", xlabel="frame", ylabel="landmarks")
    axes[0][1].set(title=f"scale over time ({SCALE_WINDOW} frames)", xlabel="time (s)", ylabel="estimated / true")
    missing = ("no run has a map", f"no run has truth over {SCALE_WINDOW + 1} frames")
    for ax, drawn, said in zip(axes[0], (mapped, scaled), missing, strict=True):
        if not drawn:
            ax.text(0.5, 0.5, said, ha="center", va="center", transform=ax.transAxes)
        _legend_below(ax)
    fig.tight_layout()
    tag = _image_tag(_png(fig), "map size and scale")
    plt.close(fig)
    return tag


def frame_strip(run: Run) -> str:
    """``STRIP_FRAMES`` frames of a run with their tracks: detected in green, carried (score 0) in red."""
    picks = np.linspace(0, len(run.frames) - 1, min(STRIP_FRAMES, len(run.frames))).round().astype(int)
    tiles = []
    for index in picks:
        frame = run.frames[index]
        tile = cv2.cvtColor(cv2.resize(frame.image, None, fx=2, fy=2, interpolation=cv2.INTER_NEAREST),
                            cv2.COLOR_GRAY2BGR)  # fmt: skip
        for x, y, score, _ in frame.tracks if frame.tracks is not None else []:
            colour = (60, 200, 60) if score > 0 else (60, 60, 230)
            cv2.circle(tile, (int(round(2 * x + 0.5)), int(round(2 * y + 0.5))), 2, colour, -1)
        cv2.putText(tile, f"frame {index}", (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 0), 1)
        tiles.append(tile)
    ok, png = cv2.imencode(".png", np.hstack(tiles))
    return _image_tag(base64.b64encode(png.tobytes()).decode(), f"frames of {run.label}")


def _median_px(errors: list[float]) -> str:
    finite = [e for e in errors if np.isfinite(e)]
    return f"{np.median(finite):.2f}" if finite else "n/a"


def _drift_table(runs: list[Run]) -> str:
    header = [
        "run", "front-end", "frames", "ATE SE3 m", "ATE Sim3 m", "RPE m", "final %", "scale drift", "lost",
        "track error px", "pair error px",
    ]  # fmt: skip
    rows = []
    for run in runs:
        poses, diagnostics = run.poses, [f.diagnostics for f in run.frames if f.diagnostics is not None]
        figures = drift.summary(poses[2], poses[1]) if poses is not None else None
        cells = [
            run.label, str(run.metadata.get("frontend", "?")), str(len(run.frames)),
            *(f"{figures[k]:.4f}" if figures else "n/a" for k in ("ate_se3", "ate_sim3", "rpe_trans")),
            f"{figures['final_drift_pct']:.2f}" if figures else "n/a",
            f"{figures['scale_drift']:.3f}" if figures else "n/a",
            str(sum(d.lost for d in diagnostics)) if diagnostics else "n/a",
            _median_px([d.correspondence_error_px for d in diagnostics]),
            _median_px([d.pair_error_px for d in diagnostics]),
        ]  # fmt: skip
        rows.append("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in cells) + "</tr>")
    return "<table><tr>" + "".join(f"<th>{h}</th>" for h in header) + "</tr>" + "".join(rows) + "</table>"


SETTINGS = ("version", "replayed_from", "frontend", "scenario", "tracker", "odometry")  # the metadata shown, in order


def _settings(run: Run) -> str:
    """The run's settings, a line each: dotted name (``odometry.map.window``) and value, every one shown."""
    leaves = [leaf for key in SETTINGS if key in run.metadata for leaf in _flat(key, run.metadata[key])]
    if not leaves:
        return "<p>No settings in the log.</p>"
    width = max(len(name) for name, _ in leaves)
    lines = [f"{name:<{width}}  {_shown(value)}" for name, value in leaves]
    return f"<pre class='settings'>{html.escape(chr(10).join(lines))}</pre>"


def _shown(value) -> str:
    """A setting's value as text: a string as it is, anything else as JSON."""
    return value if isinstance(value, str) else json.dumps(value)


def _flat(name: str, value) -> list[tuple[str, object]]:
    """(dotted name, value) of every leaf of a nested dict."""
    if not isinstance(value, dict):
        return [(name, value)]
    return [leaf for key, inner in value.items() for leaf in _flat(f"{name}.{key}", inner)]


STYLE = """body{font-family:sans-serif;margin:1.5em;color:#222}table{border-collapse:collapse;margin:1em 0}
td,th{border:1px solid #bbb;padding:.3em .7em;text-align:right}th{background:#eee}
img{max-width:100%;display:block;margin:.5em 0}.note{color:#a33}.runs{display:flex;gap:1.5em;flex-wrap:wrap}
.run{flex:1;min-width:30em}pre{background:#f6f6f6;padding:.6em;font-size:.8em;white-space:pre-wrap}"""


def write_report(paths: list[Path], out: Path) -> list[str]:
    """Write the HTML report of the logs ``paths`` to ``out`` (never over one of them; by way of
    ``out.partial``); returns one line per log that could not be read at all and per loss in the logs read (a
    cut-off file), each once (the page says so too). LogError if none could."""
    runs, unreadable = [], []
    for path in paths:
        try:
            runs.append(load_run(Path(path)))
        except LogError as error:
            unreadable.append(str(error))
    if not runs:
        raise LogError("no log could be read: " + "; ".join(unreadable))
    names = distinct_names([run.path for run in runs])
    for run in runs:
        run.name = names[str(run.path)]
    sections = [f"<p class='note'>{html.escape(line)}</p>" for line in unreadable]
    sections += ["<h2>Drift</h2>", _drift_table(runs), trajectory_figures(runs), "<h2>Tracking</h2>",
                 tracking_figure(runs), "<h2>Map and scale</h2>", map_figure(runs),
                 "<h2>Runs</h2><div class='runs'>"]  # fmt: skip
    for run in runs:
        notes = "".join(f"<p class='note'>{html.escape(n)}</p>" for n in run.notes)
        sections.append(
            f"<div class='run'><h3>{html.escape(run.label)}</h3>{notes}{frame_strip(run)}{_settings(run)}</div>"
        )
    sections.append("</div>")
    page = (
        f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>deepslam report</title><style>{STYLE}</style>"
        f"</head><body><h1>deepslam report: {html.escape(', '.join(r.label for r in runs))}</h1>"
        + "".join(sections)
        + "</body></html>"
    )
    with written(out, inputs=tuple(paths)) as partial:
        partial.write_text(page)
    return list(dict.fromkeys([*unreadable, *(line for run in runs for line in run.lost)]))
