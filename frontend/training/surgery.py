"""Weight surgery for fine-tuning stages: starting a wider or deeper network from trained weights so
that it computes the same function at step 0 (``--init``)."""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch
from torch import nn

from deepslam.errors import InputError
from deepslam.frontend.config import MagicWarpConfig
from deepslam.frontend.magicwarp import MagicWarpNet
from deepslam.frontend.nets import read_weights

WIDENABLE = {"widths", "hidden", "head", "pool"}  # config fields --init may change: more units, weightless pooling


def embed_weights(model: nn.Module, weights: dict) -> None:
    """Load the state dict of a narrower network of the same layout (wider layers only) into
    ``model`` so that it computes the same function.

    Every tensor is copied into the leading slice of the wider one; old units get zero weights from
    the new inputs, new units keep their fresh initialisation, so they start to learn without
    changing the output. Holds for chains of convolutions, BatchNorm, pooling and linear layers with
    channel-major flattening. Raises ValueError if a tensor is missing or smaller in ``model``.
    """
    target = model.state_dict()
    if set(target) != set(weights):
        raise InputError("the weights have other layers than the network")
    for name, old in weights.items():
        new = target[name]
        if old.dim() != new.dim() or any(o > n for o, n in zip(old.shape, new.shape, strict=False)):
            raise InputError(f"{name}: {tuple(old.shape)} does not fit into {tuple(new.shape)}")
        if old.dim() >= 2:
            new[: old.shape[0], old.shape[1] :] = 0
        new[tuple(slice(0, size) for size in old.shape)] = old
    model.load_state_dict(target)


def deepened(config: MagicWarpConfig, weights: dict, blocks: int) -> tuple[MagicWarpConfig, dict]:
    """The config and state dict of the network ``config`` with ``blocks`` VGG blocks per stage.

    Each stage keeps its blocks and gains new ones of its last width after them, each passing its
    input through: an identity 3x3 convolution, then a BatchNorm whose scale and shift undo its own
    normalisation of the input statistics the previous BatchNorm implies (mean and variance of a
    rectified Gaussian of that BatchNorm's shift and scale). The deeper network computes the same
    function in eval mode and nearly the same while training (batch statistics).
    """
    if blocks < config.blocks:
        raise InputError(f"cannot remove blocks ({config.blocks} per stage) and keep the function")
    old, stages = config.blocks, len(config.widths) // config.blocks
    grown = {name: tensor for name, tensor in weights.items() if not name.startswith("encoder.")}
    widths = []
    for stage in range(stages):
        stage_widths = list(config.widths[stage * old : (stage + 1) * old])
        widths += stage_widths + stage_widths[-1:] * (blocks - old)
        for block in range(blocks):
            source, target = (
                f"encoder.{stage * (old + 1) + min(block, old - 1)}.",
                f"encoder.{stage * (blocks + 1) + block}.",
            )
            layer = {name[len(source) :]: tensor for name, tensor in weights.items() if name.startswith(source)}
            if block >= old:
                layer = _identity_block(layer["1.weight"], layer["1.bias"])
            grown.update({target + name: tensor for name, tensor in layer.items()})
    return MagicWarpConfig(tuple(widths), config.pooled, config.hidden, blocks), grown


def _identity_block(scale: torch.Tensor, shift: torch.Tensor, eps: float = 1e-5) -> dict:
    """State dict of a VGG block of ``len(scale)`` channels that passes on the output of a block whose
    BatchNorm has ``scale`` and ``shift``: ReLU of roughly N(shift, scale^2) per channel. ``eps`` is
    BatchNorm2d's default."""
    width = len(scale)
    conv = torch.zeros(width, width, 3, 3)
    conv[:, :, 1, 1] = torch.eye(width)
    spread = scale.abs()
    ratio = shift / spread.clamp(min=1e-6)
    below, density = torch.special.ndtr(ratio), torch.exp(-(ratio**2) / 2) / np.sqrt(2 * np.pi)
    mean = shift * below + spread * density
    variance = ((shift**2 + spread**2) * below + shift * spread * density - mean**2).clamp(min=0)
    return {
        "0.weight": conv,
        "0.bias": torch.zeros(width),
        "1.weight": torch.sqrt(variance + eps),
        "1.bias": mean,
        "1.running_mean": mean.clone(),
        "1.running_var": variance,
        "1.num_batches_tracked": torch.tensor(0),
    }


def config_of(model: torch.nn.Module, saved: dict):
    """``saved`` (a network config as a file stores it) as ``model``'s config class, with fields newer
    than the file at their defaults; None if it is not a config of that class."""
    try:
        return type(model.config)(**saved)
    except (TypeError, ValueError):
        return None


def load_weights(model: torch.nn.Module, path: Path) -> None:
    """Load the weights of a checkpoint or shipped file into ``model`` (its averaged weights if any).
    Weights of a network that differs only by narrower ``widths`` / ``hidden`` layers are embedded
    (``embed_weights``), and a network with fewer blocks per stage is first deepened
    (``deepened``, MagicWarp only): the larger network starts from the same function."""
    if not Path(path).exists():
        raise FileNotFoundError(f"no weights to start from at {path}")
    config, weights = read_weights(path)
    saved, wanted = config_of(model, config), asdict(model.config)
    other_shape = f"{path} holds a network of another shape ({config}), not {wanted}"
    if saved is None:
        raise InputError(f"{other_shape}: its layout differs")
    try:
        if isinstance(model, MagicWarpNet) and saved.blocks != model.config.blocks:
            saved, weights = deepened(saved, weights, model.config.blocks)
        if saved == model.config:
            model.load_state_dict(weights)
            return
        if not {key for key, value in asdict(saved).items() if value != wanted[key]} <= WIDENABLE:
            raise InputError("its layout differs")
        embed_weights(model, weights)
    except ValueError as error:
        raise InputError(f"{other_shape}: {error}") from None
