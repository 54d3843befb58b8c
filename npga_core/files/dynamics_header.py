"""The `dynamics` and `cnn` sections of an `.npga` header: parsing, checking, the tensors they imply, writing.

Format version 1 holds NPGA's two networks, ``dynamics.F`` and ``dynamics.G`` (fixed inputs mu, f, z) and a
``rotation_op``. Version 2 holds any number of named networks (``dynamics.networks``, in evaluation order),
each with its inputs, activations, skips, routes and blend weight, plus the attribute composition ``rules``, the
``condition`` part of the frame vector and how the blend weights were made (``blend``). See docs/FORMAT.md.
"""

from __future__ import annotations

import re
from typing import Annotated, Any, Literal, TypeVar

import msgspec
import numpy as np
import torch
from msgspec import Meta

from npga_core.errors import brief
from npga_core.model.cnn import CNNConfig, ScreenCNN
from npga_core.model.dynamics import RULES, ConditionedMLP, Dynamics, MLPConfig
from npga_core.schema import SchemaError, Text, decode

T = TypeVar("T")
MAX_NETWORKS = 16
NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,31}")
#: Bound on the multiply-adds per Gaussian of all networks together (GHA's default sizes need about 0.9e6).
MAX_MACS_PER_GAUSSIAN = 2e7


class HeaderError(ValueError):
    """A problem with the dynamics or CNN sections of a header."""


class _DynamicsV1(msgspec.Struct):
    """Format version 1: NPGA's F and G (each an `MLPConfig` description) and how rotations compose."""

    F: dict[str, Any] | None = None
    G: dict[str, Any] | None = None
    rotation_op: Literal["compose", "add"] = "compose"


class _DynamicsV2(msgspec.Struct):
    """Format version 2: named networks in evaluation order, attribute rules, the condition, blend notes."""

    networks: Annotated[dict[Annotated[str, Meta(pattern=f"^{NAME.pattern}$")], dict[str, Any]],
                        Meta(min_length=1, max_length=MAX_NETWORKS)]
    rules: dict[str, str] = {}
    condition: dict[str, Any] | None = None
    blend: dict[str, Text] = {}


def _section(dyn: object, schema: type[T]) -> T:
    """The decoded `dynamics` section (HeaderError naming the field)."""
    try:
        return decode(dyn, schema, "dynamics")
    except SchemaError as e:
        raise HeaderError(str(e)) from None


def network_configs(dyn: dict, version: int) -> dict[str, MLPConfig]:
    """Name -> architecture of every network of a `dynamics` section (HeaderError if malformed)."""
    if version == 1:
        v1 = _section(dyn, _DynamicsV1)
        raw = {k: c for k, c in (("F", v1.F), ("G", v1.G)) if c is not None}
        if not raw:
            raise HeaderError("dynamics has neither F nor G")
        where = "dynamics.{}"
    else:
        raw, where = _section(dyn, _DynamicsV2).networks, "dynamics.networks.{}"
    try:
        out = {key: MLPConfig.from_json(cfg, where.format(key)) for key, cfg in raw.items()}
    except ValueError as e:
        raise HeaderError(str(e)) from None
    if version == 1 and "F" in out and [n for n, _ in out["F"].outputs] != ["position"]:
        raise HeaderError("dynamics.F must output exactly the 'position' block")
    macs = sum(c.flops_per_gaussian() / 2 for c in out.values())
    if macs > MAX_MACS_PER_GAUSSIAN:
        raise HeaderError(f"the networks need {macs:.3g} multiply-adds per Gaussian (at most "
                          f"{MAX_MACS_PER_GAUSSIAN:.0e})")
    return out


def rules_of(dyn: dict, version: int) -> dict[str, str]:
    """The attribute composition rules of a `dynamics` section."""
    if version == 1:
        return {"rotation": _section(dyn, _DynamicsV1).rotation_op}
    rules = _section(dyn, _DynamicsV2).rules
    for a, r in rules.items():
        if a not in RULES or r not in RULES[a]:
            raise HeaderError(f"dynamics.rules: {brief(a)} -> {brief(r)} is not a known attribute rule")
    return dict(rules)


def check_dynamics(dyn: dict, version: int) -> None:
    """Check a `dynamics` section as far as the header alone allows (HeaderError)."""
    configs = network_configs(dyn, version)
    rules_of(dyn, version)
    if version >= 2 and any(c.condition_dim for c in configs.values()) and not _section(dyn, _DynamicsV2).condition:
        raise HeaderError("the networks take a condition, but dynamics.condition does not describe it")


def dynamics_tensors(dyn: dict, version: int) -> dict[str, tuple[str, tuple[int, ...]]]:
    """name -> (dtype, shape) of every tensor of a `dynamics` section."""
    spec: dict[str, tuple[str, tuple[int, ...]]] = {}
    for key, cfg in network_configs(dyn, version).items():
        spec[f"dynamics.{key}.input_shift"] = ("float32", (cfg.raw_input_dim,))
        spec[f"dynamics.{key}.input_scale"] = ("float32", (cfg.raw_input_dim,))
        for i, (o, fan_in) in enumerate(cfg.layer_shapes()):
            spec[f"dynamics.{key}.layers.{i}.weight"] = ("float32", (o, fan_in))
            spec[f"dynamics.{key}.layers.{i}.bias"] = ("float32", (o,))
    return spec


def cnn_tensors(cnn: dict) -> dict[str, tuple[str, tuple[int, ...]]]:
    """name -> (dtype, shape) of every tensor of a `cnn` section."""
    spec: dict[str, tuple[str, tuple[int, ...]]] = {}
    for i, layer in enumerate(CNNConfig.from_json(cnn).layers):
        spec[f"cnn.layers.{i}.weight"] = ("float32", (layer.out_channels, layer.in_channels, layer.kernel,
                                                      layer.kernel))
        if layer.bias:
            spec[f"cnn.layers.{i}.bias"] = ("float32", (layer.out_channels,))
    return spec


def build_dynamics(dyn: dict, version: int, t: dict[str, np.ndarray]) -> Dynamics:
    """The `Dynamics` of a checked `dynamics` section with its tensors."""
    nets = {}
    for key, cfg in network_configs(dyn, version).items():
        net = ConditionedMLP(cfg)
        prefix = f"dynamics.{key}."
        state = {name[len(prefix):]: torch.from_numpy(np.array(a)) for name, a in t.items() if name.startswith(prefix)}
        net.load_state_dict(state, strict=True)
        nets[key] = net.eval()
    return Dynamics(networks=nets, rules=rules_of(dyn, version),
                    condition=dyn.get("condition") if version >= 2 else None,
                    blend_notes=dyn.get("blend", {}) if version >= 2 else None)


def build_cnn(cnn: dict, t: dict[str, np.ndarray]) -> ScreenCNN:
    """The `ScreenCNN` of a checked `cnn` section with its tensors."""
    model = ScreenCNN(CNNConfig.from_json(cnn))
    state = {}
    for i, layer in enumerate(model.config.layers):
        state[f"convs.{i}.weight"] = torch.from_numpy(np.array(t[f"cnn.layers.{i}.weight"]))
        if layer.bias:
            state[f"convs.{i}.bias"] = torch.from_numpy(np.array(t[f"cnn.layers.{i}.bias"]))
    model.load_state_dict(state, strict=True)
    return model.eval()


def dynamics_section(dyn: Dynamics, version: int) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """The `dynamics` header section of `dyn` in a format version, and its arrays."""
    arrays: dict[str, np.ndarray] = {}
    for key, net in dyn.networks().items():
        for name, tensor in net.state_dict().items():
            arrays[f"dynamics.{key}.{name}"] = tensor.detach().cpu().numpy()
    if version == 1:
        section: dict[str, Any] = {"rotation_op": dyn.rotation_op, "F": None, "G": None}
        for key, net in dyn.networks().items():
            section[key] = net.config.to_json()
        return section, arrays
    return {"rules": dict(dyn.rules), "condition": dyn.condition, "blend": dict(dyn.blend_notes),
            "networks": {key: net.config.to_json() for key, net in dyn.networks().items()}}, arrays


def cnn_section(cnn: ScreenCNN) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """The `cnn` header section and its arrays."""
    arrays = {}
    for i, conv in enumerate(cnn.convs):
        arrays[f"cnn.layers.{i}.weight"] = conv.weight.detach().cpu().numpy()  # type: ignore[operator]
        if conv.bias is not None:
            arrays[f"cnn.layers.{i}.bias"] = conv.bias.detach().cpu().numpy()  # type: ignore[operator]
    return cnn.config.to_json(), arrays
