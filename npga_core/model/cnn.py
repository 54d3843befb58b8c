"""The optional screen-space CNN: maps the rendered image (RGB and/or latent channels) to the final RGB image.

Two descriptions, one module:

- `layers` (format version 1, NPGA's refinement): 2D convolutions with 'same' padding and bias, each followed
  by an activation (or none), input [RGB, latent], optionally residual on the RGB.
- `ops` (format version 2): a sequence of operations, each one of ``conv`` (kernel, bias or not), ``instance_norm``
  (no affine parameters, as `torch.nn.InstanceNorm2d` by default), ``act`` (an activation) and ``upsample``
  (factor, bilinear or nearest, aligned corners or not). Gaussian-Head-Avatar's super-resolution network
  (3x3 convolutions without bias, instance normalisation, ReLU, bilinear x2 upsampling with aligned corners,
  a 1x1 output convolution and a sigmoid) is one case. `input` says which channels the CNN takes ("rgb+latent"
  or "latent" alone) and `latent_background` the value of the latent channels where no Gaussian covers a pixel
  (GHA trains its 32-channel images over a background of 1 in every channel).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Annotated

import msgspec
import numpy as np
import torch
from msgspec import Meta
from torch import nn

from npga_core.errors import brief
from npga_core.model.networks import ACTIVATIONS
from npga_core.schema import decode

#: Bounds a header cannot exceed (a file claiming more is refused before anything is allocated or run).
MAX_KERNEL = 15
MAX_CHANNELS = 4096
MAX_OPS = 256
MAX_UPSAMPLE = 16
MAX_MACS_PER_PIXEL = 5e7  # multiply-adds per input pixel; GHA's upsampler at its default width needs ~4.4e6


@dataclass
class ConvLayer:
    """One 2D convolution with 'same' padding and an activation (None for the last layer)."""

    in_channels: int
    out_channels: int
    kernel: int = 3
    activation: str | None = "relu"
    bias: bool = True


@dataclass
class CNNConfig:
    """Architecture of the screen-space CNN as stored in the checkpoint header (see the module docstring)."""

    layers: list[ConvLayer] = field(default_factory=list)
    residual: bool = True  # output = input RGB + CNN(input)
    ops: list[dict] | None = None
    input: str = "rgb+latent"
    latent_background: float = 0.0

    def __post_init__(self) -> None:
        if self.ops is None:
            ops: list[dict] = []
            for c in self.layers:
                ops.append({"op": "conv", "in": c.in_channels, "out": c.out_channels, "kernel": c.kernel,
                            "bias": c.bias})
                if c.activation is not None:
                    ops.append({"op": "act", "name": c.activation})
            self.ops = ops
        else:
            self.layers = [ConvLayer(o["in"], o["out"], o["kernel"], None, o.get("bias", True))
                           for o in self.ops if o.get("op") == "conv"]

    @property
    def in_channels(self) -> int:
        return self.layers[0].in_channels

    @property
    def upsample(self) -> int:
        """Output size / input size (the product of the upsampling factors)."""
        return math.prod(int(o["factor"]) for o in self.ops or [] if o["op"] == "upsample")

    def input_channels(self, latent_dim: int) -> int:
        """Channels of the image this CNN takes from an avatar with `latent_dim` latent channels."""
        return latent_dim + (3 if self.input == "rgb+latent" else 0)

    def band_halo(self) -> int | None:
        """Rows of context a horizontal band needs for the output of the whole image, or None when the CNN
        cannot run in bands (instance normalisation uses the whole image; upsampling changes the grid)."""
        if any(o["op"] in ("instance_norm", "upsample") for o in self.ops or []):
            return None
        return sum(c.kernel // 2 for c in self.layers)

    def macs_per_pixel(self) -> float:
        """Multiply-adds per input pixel of one forward pass."""
        macs, area = 0.0, 1.0
        for o in self.ops or []:
            if o["op"] == "upsample":
                area *= o["factor"] ** 2
            elif o["op"] == "conv":
                macs += area * o["in"] * o["out"] * o["kernel"] ** 2
        return macs

    def validate(self, latent_dim: int | None = None) -> None:
        """Raise ValueError if the operations do not chain, exceed the bounds or do not end in 3 channels."""
        ops = self.ops or []
        if not self.layers:
            raise ValueError("CNN has no layers")
        if len(ops) > MAX_OPS:
            raise ValueError(f"CNN has {len(ops)} operations (at most {MAX_OPS})")
        if self.input not in ("rgb+latent", "latent"):
            raise ValueError(f"CNN input {brief(self.input)} is not 'rgb+latent' or 'latent'")
        channels = None
        for i, o in enumerate(ops):
            channels = _check_op(i, o, channels)
        if self.upsample > MAX_UPSAMPLE:
            raise ValueError(f"CNN upsamples by {self.upsample} in all (at most {MAX_UPSAMPLE})")
        if self.macs_per_pixel() > MAX_MACS_PER_PIXEL:
            raise ValueError(f"CNN needs {self.macs_per_pixel():.3g} multiply-adds per pixel "
                             f"(at most {MAX_MACS_PER_PIXEL:.0e})")
        if channels != 3:
            raise ValueError(f"CNN ends with {channels} channels, expected 3 (RGB)")
        if self.residual and (self.input != "rgb+latent" or self.upsample != 1):
            raise ValueError("a residual CNN needs the RGB input and no upsampling")
        if latent_dim is not None and self.in_channels != self.input_channels(latent_dim):
            detail = f"3 + {latent_dim}" if self.input == "rgb+latent" else f"{latent_dim} latent"
            raise ValueError(f"CNN takes {self.in_channels} channels, the avatar renders {detail}")

    @property
    def simple(self) -> bool:
        """Expressible in format version 1 (convolutions with bias and activations, RGB + latent input)."""
        if self.input != "rgb+latent" or self.latent_background != 0.0:
            return False
        ops = self.ops or []
        for i, o in enumerate(ops):
            if o["op"] == "conv" and not o.get("bias", True):
                return False
            if o["op"] not in ("conv", "act") or (o["op"] == "act" and (i == 0 or ops[i - 1]["op"] != "conv")):
                return False
        return True

    def to_json(self) -> dict:
        if self.simple:
            acts = [None] * len(self.layers)
            ci = -1
            for o in self.ops or []:
                if o["op"] == "conv":
                    ci += 1
                else:
                    acts[ci] = o["name"]
            return {"residual": self.residual,
                    "layers": [[c.in_channels, c.out_channels, c.kernel, a] for c, a in zip(self.layers, acts,
                                                                                           strict=True)]}
        return {"residual": self.residual, "input": self.input, "latent_background": self.latent_background,
                "ops": [dict(o) for o in self.ops or []]}

    @staticmethod
    def from_json(d: object, where: str = "cnn") -> CNNConfig:
        """The checked architecture of a header's `cnn` section (`_CNNJson`); ValueError naming `where` and the
        field."""
        j: _CNNJson = decode(d, _CNNJson, where)
        try:
            if j.ops is not None:
                cfg = CNNConfig(residual=j.residual, ops=[msgspec.to_builtins(o) for o in j.ops], input=j.input,
                                latent_background=j.latent_background)
            elif j.layers is not None:
                cfg = CNNConfig([ConvLayer(i, o, k, a) for i, o, k, a in j.layers], j.residual)
            else:
                raise ValueError("malformed CNN architecture: neither layers nor ops given")
            cfg.validate()
        except ValueError as e:
            raise ValueError(f"{where}: {e}") from None
        return cfg


# The header's description of the CNN, declared (msgspec; `CNNConfig.validate` checks the rest).
_Int = Annotated[int, Meta(ge=-(2**31), le=2**31 - 1)]
_Str = Annotated[str, Meta(max_length=64)]


class _Conv(msgspec.Struct, tag_field="op", tag="conv"):
    in_: _Int = msgspec.field(name="in")
    out: _Int
    kernel: _Int
    bias: bool = True


class _Act(msgspec.Struct, tag_field="op", tag="act"):
    name: _Str


class _InstanceNorm(msgspec.Struct, tag_field="op", tag="instance_norm"):
    eps: Annotated[float, Meta(ge=-1e6, le=1e6)] = 1e-5


class _Upsample(msgspec.Struct, tag_field="op", tag="upsample"):
    factor: _Int
    mode: _Str = "bilinear"
    align_corners: bool = False


class _CNNJson(msgspec.Struct):
    residual: bool = True
    layers: Annotated[list[tuple[_Int, _Int, _Int, _Str | None]], Meta(max_length=MAX_OPS)] | None = None
    ops: Annotated[list[_Conv | _Act | _InstanceNorm | _Upsample], Meta(max_length=MAX_OPS)] | None = None
    input: _Str = "rgb+latent"
    latent_background: Annotated[float, Meta(ge=-1e6, le=1e6)] = 0.0


class ScreenCNN(nn.Module):
    """The screen-space network: the paper's refinement CNN, or a super-resolution network (see the module
    docstring)."""

    def __init__(self, config: CNNConfig):
        super().__init__()
        config.validate()
        self.config = config
        self.convs = nn.ModuleList(
            nn.Conv2d(c.in_channels, c.out_channels, c.kernel, padding=c.kernel // 2, bias=c.bias)
            for c in config.layers
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """x: (B, C, height, width) -> (B, 3, height * upsample, width * upsample)."""
        h = x
        for step in self.steps(x):
            h = step
        return h

    def steps(self, x: torch.Tensor) -> Iterator[torch.Tensor]:
        """The forward pass one operation at a time: yields the activations after each (the output last), so a
        caller can stop between operations."""
        h = x
        convs = iter(self.convs)
        ops = self.config.ops or []
        for i, o in enumerate(ops):
            kind = o["op"]
            if kind == "conv":
                h = next(convs)(h)
            elif kind == "act":
                h = ACTIVATIONS[o["name"]](h)
            elif kind == "instance_norm":
                h = nn.functional.instance_norm(h, eps=o["eps"])
            else:
                h = nn.functional.interpolate(h, scale_factor=o["factor"], mode=o["mode"],
                                              align_corners=o["align_corners"] if o["mode"] == "bilinear" else None)
            if i == len(ops) - 1 and self.config.residual:
                h = x[:, :3] + h
            yield h

    @property
    def device(self) -> torch.device:
        """Where the weights are (the input goes there, the output comes back to the CPU)."""
        return self.convs[0].weight.device  # type: ignore[return-value]

    def assemble(self, rgb: np.ndarray | None, latent: np.ndarray | None, alpha: np.ndarray | None) -> np.ndarray:
        """The CNN's input image (H, W, C) from the rendered RGB (over the background), the composited latent
        image (no background) and the alpha: [rgb, latent] or the latent over `latent_background`."""
        c = self.config
        if c.input == "latent":
            if latent is None:
                raise ValueError("this CNN takes the latent image")
            if c.latent_background != 0.0:
                if alpha is None:
                    raise ValueError("the latent background needs the alpha image")
                latent = latent + (1.0 - alpha)[..., None] * np.float32(c.latent_background)
            return np.ascontiguousarray(latent, np.float32)
        if rgb is None:
            raise ValueError("this CNN takes the RGB image")
        return np.concatenate([rgb, latent], axis=2) if latent is not None and latent.shape[2] else rgb

    def refine(self, image: np.ndarray) -> np.ndarray:
        """Refine an (H, W, C) float image into (H*s, W*s, 3) float32, clamped to [0, 1], on `device`."""
        return run_cnn(self, image, self.device)


@torch.no_grad()
def run_cnn_steps(cnn: ScreenCNN, image: np.ndarray, cancelled: Callable[[], bool]) -> np.ndarray | None:
    """`run_cnn` on the CNN's device one operation at a time; None as soon as `cancelled()` is true between two
    operations (for CNNs that cannot run in bands: a refinement the view has left stops within one operation)."""
    x = torch.from_numpy(np.ascontiguousarray(image, dtype=np.float32)).permute(2, 0, 1)[None]
    x = x.to(cnn.device).contiguous(memory_format=torch.channels_last)
    out = None
    for step in cnn.steps(x):
        if cancelled():
            return None
        out = step
    assert out is not None
    return out[0].clamp_(0.0, 1.0).permute(1, 2, 0).contiguous().cpu().numpy()


@torch.no_grad()
def run_cnn(module: nn.Module, image: np.ndarray, device: torch.device) -> np.ndarray:
    """An (H, W, C) float image through `module` (a `ScreenCNN`, or a traced copy of one) on `device`:
    (H', W', 3) float32 clamped to [0, 1], on the CPU. The input goes in channels-last layout (the HWC image as it
    is), which the CPU convolutions run about 3x faster on than NCHW (measured 0.21 s vs 0.71 s at 550 x 802)."""
    x = torch.from_numpy(np.ascontiguousarray(image, dtype=np.float32)).permute(2, 0, 1)[None]
    x = x.to(device).contiguous(memory_format=torch.channels_last)
    out = module(x)[0].clamp_(0.0, 1.0).permute(1, 2, 0)
    return out.contiguous().cpu().numpy()


def _check_op(i: int, o: dict, channels: int | None) -> int | None:
    """Check operation `i` of a CNN against the bounds and the channels before it; the channels after it."""
    kind = o.get("op")
    if kind == "conv":
        if not 1 <= o["kernel"] <= MAX_KERNEL or o["kernel"] % 2 == 0:
            raise ValueError(f"CNN layer {i} kernel {o['kernel']} must be odd and in 1..{MAX_KERNEL}")
        if not (1 <= o["in"] <= MAX_CHANNELS and 1 <= o["out"] <= MAX_CHANNELS):
            raise ValueError(f"CNN layer {i} has {o['in']} -> {o['out']} channels (at most {MAX_CHANNELS})")
        if channels is not None and o["in"] != channels:
            raise ValueError(f"CNN layer {i} takes {o['in']} channels, the layer before gives {channels}")
        return o["out"]
    if kind == "act":
        if o["name"] not in ACTIVATIONS:
            raise ValueError(f"CNN layer {i} has unknown activation {brief(o['name'])}")
    elif kind == "upsample":
        if not 2 <= o["factor"] <= MAX_UPSAMPLE or o.get("mode") not in ("bilinear", "nearest"):
            raise ValueError(f"CNN upsampling {i} must be bilinear or nearest by 2..{MAX_UPSAMPLE}")
    elif kind == "instance_norm":
        if not 0.0 < o.get("eps", 1e-5) < 1.0:
            raise ValueError(f"CNN instance norm {i} eps outside (0, 1)")
    else:
        raise ValueError(f"CNN operation {i} is {brief(kind)} (conv, act, instance_norm, upsample)")
    return channels
