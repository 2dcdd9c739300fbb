"""Building blocks shared by MagicPoint and MagicWarp: the VGG block and BatchNorm folding for inference."""

from __future__ import annotations

import copy
import pickle
import struct
import zipfile
from pathlib import Path

import torch
from torch import nn

from deepslam.errors import InputError


def vgg_block(in_channels: int, out_channels: int, kernel_size: int = 3) -> nn.Sequential:
    """Convolution (same padding), BatchNorm, ReLU."""
    return nn.Sequential(
        nn.Conv2d(in_channels, out_channels, kernel_size, padding=kernel_size // 2),
        nn.BatchNorm2d(out_channels),
        nn.ReLU(inplace=True),
    )


class BlurMaxPool(nn.Module):
    """Anti-aliased 2x2 max-pool (Zhang, *Making Convolutional Networks Shift-Invariant Again*, 2019): the
    max over every 2x2 window (stride 1, the last row and column repeated), then a 3x3 binomial blur
    ([1, 2, 1] x [1, 2, 1] / 16, reflected at the top and left) sampled at every second pixel.
    (B, C, H, W) -> (B, C, H/2, W/2) for even H and W, as ``nn.MaxPool2d(2)``; no weights. Written with
    slices rather than a depthwise convolution, which ran 3-8x slower on one CPU thread."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        for dim in (2, 3):
            x = torch.cat([x, x.narrow(dim, -1, 1)], dim)
            x = torch.maximum(x.narrow(dim, 0, x.shape[dim] - 1), x.narrow(dim, 1, x.shape[dim] - 1))
        for dim in (2, 3):
            even, odd = _every_second(x, dim, 0), _every_second(x, dim, 1)
            before = torch.cat([odd.narrow(dim, 0, 1), odd.narrow(dim, 0, odd.shape[dim] - 1)], dim)
            x = before.add_(odd).add_(even, alpha=2.0)  # x[2i - 1] + 2 x[2i] + x[2i + 1]
        return x.mul_(1.0 / 16.0)  # in the input's memory layout (channels-last in a folded network)


def _every_second(x: torch.Tensor, dim: int, start: int) -> torch.Tensor:
    return x[:, :, start::2] if dim == 2 else x[:, :, :, start::2]


def pooling(kind: str) -> nn.Module:
    """The 2x2 downsampling of a network config: "max" (the paper's) or "blur" (``BlurMaxPool``)."""
    return BlurMaxPool() if kind == "blur" else nn.MaxPool2d(2)


class OneDnnConv2d(nn.Conv2d):
    """A Conv2d that runs on oneDNN for float32 CPU inputs, whatever their size.

    PyTorch picks its reference kernel (im2col and a matrix product) for batch-1 3x3 convolutions of
    inputs up to 20,480 values; for the one-channel image layer of MagicPoint at 160x120 that kernel took
    1.9 ms against oneDNN's 0.2 ms here (one thread). Other devices and dtypes, and builds without oneDNN
    or with it switched off (``torch.backends.mkldnn.enabled``), take the usual path."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        onednn = torch.backends.mkldnn.is_available() and torch.backends.mkldnn.enabled
        if x.device.type != "cpu" or x.dtype != torch.float32 or not onednn:
            return super().forward(x)
        return torch.ops.aten.mkldnn_convolution(
            x, self.weight, self.bias, self.padding, self.stride, self.dilation, self.groups
        )


def fold_batchnorm(model: nn.Module) -> nn.Module:
    """A copy of ``model`` in eval mode with every Conv2d+BatchNorm2d pair merged into the Conv2d,
    its weights stored channels-last (NHWC), the layout oneDNN's CPU convolutions run fastest (measured
    1.5-4x on one thread here). Convolutions of a one-channel input become ``OneDnnConv2d``.

    The BatchNorm becomes an identity; outputs equal the unfolded model's in eval mode.
    """
    folded = copy.deepcopy(model).eval()
    for module in folded.modules():
        children = list(module.named_children())
        for (_, conv), (bn_name, bn) in zip(children, children[1:], strict=False):
            if isinstance(conv, nn.Conv2d) and isinstance(bn, nn.BatchNorm2d):
                scale = bn.weight.detach() / torch.sqrt(bn.running_var + bn.eps)
                bias = conv.bias.detach() if conv.bias is not None else torch.zeros_like(bn.running_mean)
                conv.weight = nn.Parameter(conv.weight.detach() * scale[:, None, None, None])
                conv.bias = nn.Parameter((bias - bn.running_mean) * scale + bn.bias.detach())
                setattr(module, bn_name, nn.Identity())
        for name, conv in list(module.named_children()):
            if type(conv) is nn.Conv2d and conv.in_channels == 1 and _zero_padded(conv):
                setattr(module, name, _on_onednn(conv))
    return folded.to(memory_format=torch.channels_last)


def _zero_padded(conv: nn.Conv2d) -> bool:
    return conv.padding_mode == "zeros" and not isinstance(conv.padding, str)  # oneDNN takes explicit padding


def _on_onednn(conv: nn.Conv2d) -> OneDnnConv2d:
    fast = OneDnnConv2d(
        conv.in_channels,
        conv.out_channels,
        conv.kernel_size,
        conv.stride,
        conv.padding,
        conv.dilation,
        conv.groups,
        conv.bias is not None,
        device=conv.weight.device,
        dtype=conv.weight.dtype,
    )
    fast.load_state_dict(conv.state_dict())
    return fast.eval()


def parameter_bytes(model: nn.Module) -> int:
    """Size of the model's parameters and buffers in float32 bytes."""
    return sum(t.numel() * 4 for t in list(model.parameters()) + list(model.buffers()) if t.is_floating_point())


def network_config(state: dict) -> dict:
    """The network config a loaded checkpoint or shipped file was saved with, sequences as tuples (as
    ``dataclasses.asdict`` of the config gives them)."""
    return {k: tuple(v) if isinstance(v, list) else v for k, v in state["config"].items()}


def load_checkpoint(path: str | Path, needs: tuple[str, ...] = ("model", "config")) -> dict:
    """A weights file or training checkpoint as a dict, read as tensors and plain data only: a file that
    would run code when unpickled is refused, and so is one without the keys ``needs`` (ValueError)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no weights or checkpoint file at {path}")
    if not zipfile.is_zipfile(path):  # torch.save writes a zip archive
        raise InputError(f"{path} is not a deepslam weights file or checkpoint (not a torch archive)")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except (pickle.UnpicklingError, RuntimeError, EOFError, ValueError, TypeError, KeyError, struct.error) as error:
        reason = _first_line(error)
        raise InputError(f"{path} is not a deepslam weights file or checkpoint, or holds more than tensors and "
                         f"plain data; nothing in it was run ({reason})") from None  # fmt: skip
    missing = set(needs) - set(state if isinstance(state, dict) else ())
    if missing:
        raise InputError(f"{path} is not a deepslam weights file or checkpoint (no {', '.join(sorted(missing))})")
    return state


def _first_line(error: Exception) -> str:
    return str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__


def read_weights(path: Path) -> tuple[dict, dict]:
    """(network config, state dict) of shipped weights or a training checkpoint; a checkpoint's moving
    average of the weights (``--ema``) when it has one, as that is what it was validated on."""
    state = load_checkpoint(path)
    return network_config(state), state.get("ema", state["model"])


def load_network(path: Path, network: type[nn.Module], config_class: type) -> nn.Module:
    """The ``network`` (built from ``config_class``) that shipped weights or a training checkpoint at ``path``
    hold; ValueError in one line when the file holds another network (its config or its tensors do not fit)."""
    config, weights = read_weights(path)
    try:
        net = network(config_class(**config))
        net.load_state_dict(weights)
    except (TypeError, RuntimeError) as error:
        name = network.__name__.removesuffix("Net")
        raise InputError(f"{path} holds no {name} this version can run ({_first_line(error)})") from None
    return net


def resolve_device(name: str) -> str:
    """ "cpu" or "cuda" for a device option ("auto": cuda when there is one); ValueError for cuda where there
    is none."""
    if name == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    if name == "cuda" and not torch.cuda.is_available():
        raise InputError("--device cuda: this machine has no CUDA device (use cpu or auto)")
    return name
