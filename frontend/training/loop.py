"""A small resumable training loop shared by MagicPoint and MagicWarp.

Checkpoints (``last.pt``, and ``best.pt`` by the validation score) hold the model, optimiser, step,
config and the random generator state, so a run killed at any point resumes where its last
checkpoint left it. Progress shows loss, throughput and the latest validation figures.

Options every training shares (``LoopConfig``): a new run can start from another run's weights
(``init``, a fine-tuning stage), and can keep an exponential moving average of the weights (``ema``),
which is then what validation scores, ``best.pt`` keeps and ``export_weights`` ships.
"""

from __future__ import annotations

import copy
import json
import logging
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable, Literal

import numpy as np
import torch
import torch.distributed as dist
from torch.optim.swa_utils import AveragedModel, get_ema_multi_avg_fn

from deepslam.errors import InputError
from deepslam.files import written
from deepslam.frontend.nets import load_checkpoint, network_config, resolve_device
from deepslam.frontend.training.surgery import config_of, load_weights
from deepslam.progress import progress_bar

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class LoopConfig:
    """Options of the training loop itself; each network's ``TrainConfig`` extends it."""

    iterations: int = field(default=1000, metadata={"help": "total optimisation steps", "min": 1, "max": 10_000_000})
    batch: int = field(default=32, metadata={"help": "examples per step", "min": 1, "max": 4096})
    lr: float = field(default=1e-3, metadata={"help": "Adam learning rate", "min": 1e-12})
    seed: int = field(default=0, metadata={"help": "seed of the data stream and initialisation", "min": 0})
    validate_every: int = field(default=500, metadata={"help": "steps between validations/checkpoints", "min": 1})
    threads: int = field(default=1, metadata={"help": "torch CPU threads", "min": 1, "max": 256})
    ema: float = field(
        default=0.0,
        metadata={
            "help": "keep a moving average of the weights with this per-step decay (e.g. 0.999); it is what "
            "validation scores and best.pt / export ship (0: off)",
            "metavar": "DECAY",
            "min": 0,
            "max": 0.999999,
        },
    )
    device: Literal["auto", "cpu", "cuda"] = field(
        default="cpu", metadata={"help": "where to train: cpu, cuda, or auto (cuda when there is one)"}
    )
    init: str = field(
        default="",
        metadata={
            "help": "start a new run (no last.pt in --out) from these weights: a checkpoint or shipped file; "
            "weights of a narrower network (same layers, fewer units) are embedded into the wider one so that "
            "it starts from the same function",
            "metavar": "WEIGHTS",
        },
    )

    def __post_init__(self):
        problems = [
            f"--{name.replace('_', '-')} must be at least 1, got {getattr(self, name)}"
            for name in ("iterations", "batch", "validate_every", "threads")
            if getattr(self, name) < 1
        ]
        if not self.lr > 0:
            problems.append(f"--lr must be positive, got {self.lr}")
        if self.seed < 0:
            problems.append(f"--seed must be non-negative, got {self.seed}")
        if not 0 <= self.ema < 1:
            problems.append(f"--ema must lie in [0, 1), got {self.ema}")
        if problems:
            raise InputError("; ".join(problems))


def save_checkpoint(
    path: Path,
    model: torch.nn.Module,
    optimizer: torch.optim.Optimizer,
    step: int,
    rng: np.random.Generator,
    config: Any,
    extra: dict,
) -> None:
    """Write a checkpoint atomically (a killed write never leaves a broken file). ``extra`` may hold
    "ema", the averaged model's state dict, and "rngs", the generator states of every rank."""
    state = {
        "model": model.state_dict(),
        "optimizer": optimizer.state_dict(),
        "step": step,
        "rng": rng.bit_generator.state,
        "rngs": [rng.bit_generator.state],  # every rank's data stream (``extra`` has them for several ranks)
        "config": asdict(model.config),
        "train_config": asdict(config),
        **extra,
    }
    with written(path) as partial:
        torch.save(state, partial)


def export_weights(checkpoint: Path, out: Path) -> dict:
    """Write the inference part of a training checkpoint (model, configs, step; no optimiser or
    generator state) to ``out``, the form shipped in ``frontend/weights``, by way of ``out.partial`` and
    never over the checkpoint (under any name); returns what was kept."""
    state = load_checkpoint(checkpoint, needs=("model", "config", "step"))
    kept = {key: state[key] for key in ("model", "config", "step", "train_config") if key in state}
    if "ema" in state:
        kept["model"] = state["ema"]
    with written(out, inputs=(checkpoint,)) as partial:
        torch.save(kept, partial)
    return kept


@dataclass(frozen=True)
class Ranks:
    """This process's place in a data-parallel run started by torchrun (rank 0 of 1 otherwise)."""

    rank: int = 0
    world: int = 1

    @staticmethod
    def join(device: torch.device) -> Ranks:
        """Join the process group torchrun set up (gloo on CPU, nccl on CUDA), if there is one."""
        world = int(os.environ.get("WORLD_SIZE", "1"))
        if world == 1:
            return Ranks()
        if not dist.is_initialized():
            dist.init_process_group("nccl" if device.type == "cuda" else "gloo")
        return Ranks(dist.get_rank(), dist.get_world_size())

    @property
    def leader(self) -> bool:
        return self.rank == 0

    def average_gradients(self, model: torch.nn.Module) -> None:
        for parameter in model.parameters():
            if parameter.grad is not None:
                dist.all_reduce(parameter.grad)
                parameter.grad /= self.world

    def share(self, model: torch.nn.Module) -> None:
        """Rank 0's parameters and buffers (BatchNorm statistics) to every rank."""
        for tensor in [*model.parameters(), *model.buffers()]:
            dist.broadcast(tensor.data, 0)

    def check_in_step(self, model: torch.nn.Module, step: int) -> None:
        """RuntimeError unless every rank holds the same parameters."""
        total = torch.stack([p.detach().double().sum() for p in model.parameters()]).sum().reshape(1)
        totals = [torch.zeros_like(total) for _ in range(self.world)]
        dist.all_gather(totals, total)
        if any(not torch.equal(t, totals[0]) for t in totals):
            raise RuntimeError(f"the ranks' parameters differ after step {step}")


def _scored(figures: dict) -> set[str]:
    """The validation figures' names (what makes two validations comparable)."""
    return set(figures) - {"step", "wall_s", "train_loss"}


def save_curves(history: list[dict], path: Path) -> None:
    """PNG of every validation figure and the training loss against the step."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = [k for k in history[-1] if k not in ("step", "wall_s")]
    columns = min(4, len(names))
    rows = -(-len(names) // columns)
    fig, axes = plt.subplots(rows, columns, figsize=(3.6 * columns, 2.6 * rows), squeeze=False)
    steps = [h["step"] for h in history]
    for ax, name in zip(axes.ravel(), names, strict=False):
        ax.plot(steps, [h.get(name, float("nan")) for h in history], "o-", markersize=3)
        ax.set_title(name, fontsize=9)
        ax.tick_params(labelsize=7)
    for ax in axes.ravel()[len(names) :]:
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def _moving_average(model: torch.nn.Module, decay: float, state: dict | None) -> AveragedModel | None:
    """The exponential moving average of ``model``'s weights and BatchNorm statistics (None if off)."""
    if not decay:
        return None
    ema = AveragedModel(model, multi_avg_fn=get_ema_multi_avg_fn(decay), use_buffers=True)
    if state and "ema" in state:
        ema.module.load_state_dict(state["ema"])
        ema.n_averaged.fill_(1)
    return ema


def train(
    model: torch.nn.Module,
    config: LoopConfig,
    out_dir: Path,
    step_fn: Callable[[int, np.random.Generator, int], dict[str, torch.Tensor]],
    validate_fn: Callable[[torch.nn.Module], dict[str, float]],
    score_key: str,
) -> dict:
    """Run ``config.iterations`` optimisation steps (resuming from ``out_dir/last.pt``) on
    ``config.device``; under torchrun, data-parallel: each rank draws ``batch / ranks`` examples from its
    own stream, gradients are averaged, rank 0 validates and writes checkpoints.

    ``step_fn(step, rng, batch)`` builds ``batch`` examples on the model's device and returns {"loss":
    tensor, ...}; ``validate_fn(model)`` returns figures, ``score_key`` among them (higher is better)
    choosing ``best.pt``. Returns the last validation figures (rank 0; {} on the other ranks).
    """
    device = torch.device(resolve_device(config.device))
    ranks = Ranks.join(device)
    if config.batch % ranks.world:
        raise InputError(f"--batch {config.batch} does not divide among {ranks.world} ranks; use a multiple")
    model.to(device)
    out_dir.mkdir(parents=True, exist_ok=True)
    optimizer = torch.optim.Adam(model.parameters(), lr=config.lr)
    rng = np.random.default_rng(config.seed if ranks.world == 1 else [config.seed, ranks.rank])
    state, (step, best, elapsed, history) = _resume(model, optimizer, rng, config, out_dir / "last.pt", ranks)
    if step >= config.iterations and ranks.leader:
        log.info(
            f"{out_dir / 'last.pt'} is at step {step} of --iterations {config.iterations}: nothing to train; "
            "raise --iterations to train on"
        )
    if ranks.world > 1:
        ranks.share(model)
    ema = _moving_average(model, config.ema, state)
    scored = ema.module if ema else model
    figures: dict[str, float] = history[-1] if history else {}
    bar = progress_bar(total=config.iterations, initial=step, unit="it", disable=not ranks.leader)
    losses: list[float] = []
    started = time.time() - elapsed
    while step < config.iterations:
        model.train()
        out = _step(model, optimizer, step_fn(step, rng, config.batch // ranks.world), ranks, step, out_dir)
        losses.append(float(out["loss"].detach()))
        if ema:
            ema.update_parameters(model)
        step += 1
        bar.update(1)
        bar.set_postfix(
            {k: f"{float(v.detach()):.4g}" for k, v in out.items()}
            | {k: f"{v:.3g}" for k, v in figures.items() if k != "step"}
        )
        if step % config.validate_every == 0 or step == config.iterations:
            streams = _gather_streams(rng, ranks)
            if ranks.leader:
                figures, best = _validate_and_save(
                    model, scored, ema, optimizer, rng, config, out_dir, validate_fn, score_key,
                    (step, best, started, history, losses, streams, bar),
                )  # fmt: skip
            losses = []
            if ranks.world > 1:
                dist.barrier()
    bar.close()
    return figures if ranks.leader else {}


def _resume(model, optimizer, rng: np.random.Generator, config: LoopConfig, last: Path, ranks: Ranks) -> tuple:
    """Load ``last`` (the model, optimiser, this rank's stream) if it exists, else ``config.init``'s weights if
    given; returns (the checkpoint or None, (step, best score, elapsed seconds, history))."""
    if not last.exists():
        if config.init:
            load_weights(model, Path(config.init))
            log.info(f"starting from the weights of {config.init}")
        return None, (0, -np.inf, 0.0, [])
    state = load_checkpoint(last, needs=("model", "config", "optimizer", "step", "rng"))
    if config_of(model, network_config(state)) != model.config:
        raise InputError(
            f"{last} holds a network of another shape ({network_config(state)}), not "
            f"{asdict(model.config)}: resume it with its own options, or train into another folder"
        )
    streams = state.get("rngs", [state["rng"]])
    if len(streams) != ranks.world:
        raise InputError(f"{last} was trained by {len(streams)} ranks, not {ranks.world}: resume it with as many")
    model.load_state_dict(state["model"])
    optimizer.load_state_dict(state["optimizer"])
    for group in optimizer.param_groups:  # resuming with another --lr applies it (a manual schedule)
        group["lr"] = config.lr
    rng.bit_generator.state = streams[ranks.rank]
    log.info(f"resuming from {last} at step {state['step']}")
    return state, (state["step"], state["best"], state["elapsed"], state["history"])


def _step(model, optimizer, out: dict, ranks: Ranks, step: int, out_dir: Path) -> dict:
    """One optimisation step on the losses ``out`` (computed by the step function in training mode), the
    gradients averaged over ranks; stops on a non-finite loss or weight, naming the checkpoint kept."""
    if not torch.isfinite(out["loss"]) or not all(torch.isfinite(p).all() for p in model.parameters()):
        raise RuntimeError(
            f"training diverged at step {step} (loss {out['loss'].item():.4g}); {out_dir} keeps its last "
            f"good checkpoint: resume with a smaller --lr"
        )
    optimizer.zero_grad()
    out["loss"].backward()
    if ranks.world > 1:
        ranks.average_gradients(model)
    optimizer.step()
    if ranks.world > 1:
        for buffer in model.buffers():  # BatchNorm statistics: rank 0's, so that every rank holds the same
            dist.broadcast(buffer.data, 0)
        ranks.check_in_step(model, step + 1)
    return out


def _gather_streams(rng: np.random.Generator, ranks: Ranks) -> list:
    """Every rank's generator state, in rank order (so that a resumed run continues every stream)."""
    if ranks.world == 1:
        return [rng.bit_generator.state]
    streams: list = [None] * ranks.world
    dist.all_gather_object(streams, rng.bit_generator.state)
    return streams


def _validate_and_save(model, scored, ema, optimizer, rng, config, out_dir, validate_fn, score_key, progress):
    """Validate (on the CPU copy of what is scored), extend the history and curves, write best.pt and
    last.pt; returns (figures, best)."""
    step, best, started, history, losses, streams, bar = progress
    scored.eval()
    with torch.no_grad():
        measured = {name: float(value) for name, value in validate_fn(_on_cpu(scored)).items()}  # plain data
    figures = {"step": step, "wall_s": round(time.time() - started, 1), **measured}
    figures["train_loss"] = float(np.mean(losses)) if losses else float("nan")  # since the last validation
    if history and _scored(history[-1]) != _scored(figures):
        best = -np.inf  # a resumed run whose validation has changed: the old best does not compare
        bar.write("the validation figures differ from the checkpoint's: best.pt restarts from here")
    history.append(figures)
    (out_dir / "history.json").write_text(json.dumps(history, indent=1))
    save_curves(history, out_dir / "curves.png")
    bar.write(json.dumps(figures))
    extra = {"elapsed": time.time() - started, "history": history, "rngs": streams}
    if ema:
        extra["ema"] = {k: v.cpu() for k, v in ema.module.state_dict().items()}
    if figures[score_key] > best:
        best = figures[score_key]
        save_checkpoint(out_dir / "best.pt", model, optimizer, step, rng, config, {"best": best, **extra})
    save_checkpoint(out_dir / "last.pt", model, optimizer, step, rng, config, {"best": best, **extra})
    return figures, best


def _on_cpu(model: torch.nn.Module) -> torch.nn.Module:
    """``model`` itself on the CPU, or a CPU copy of it (validation runs the CPU inference code)."""
    return model if next(model.parameters()).device.type == "cpu" else copy.deepcopy(model).cpu()
