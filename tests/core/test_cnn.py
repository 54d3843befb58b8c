"""The screen-space CNN (`npga_core/model/cnn.py`) against plain torch: a stack of `torch.nn.Conv2d` layers.

FORMAT.md section 7 defines each layer as ``torch.nn.Conv2d(in, out, kernel, padding=kernel // 2)`` followed by
its activation, and the output as input RGB + last layer when `residual`; these tests build exactly that stack
from PyTorch's own modules with the same weights and compare.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch import nn

from npga_core.files.checkpoint import read_avatar, save_avatar
from npga_core.model.cnn import CNNConfig, ConvLayer, ScreenCNN, run_cnn
from npga_core.model.synthetic import make_synthetic_avatar

TORCH_ACTIVATIONS = {"relu": nn.ReLU(), "silu": nn.SiLU(), "gelu": nn.GELU(), "tanh": nn.Tanh(), "elu": nn.ELU(),
                     "leaky_relu": nn.LeakyReLU(), "softplus": nn.Softplus()}


def random_cnn(layers: list[tuple[int, int, int, str | None]], residual: bool, seed: int) -> ScreenCNN:
    cnn = ScreenCNN(CNNConfig([ConvLayer(*spec) for spec in layers], residual))
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in cnn.parameters():
            p.copy_(torch.randn(p.shape, generator=gen) * 0.3)
    return cnn


def torch_stack(cnn: ScreenCNN) -> nn.Sequential:
    """The same network built from nn.Conv2d and nn activations, weights copied."""
    mods: list[nn.Module] = []
    for conv, spec in zip(cnn.convs, cnn.config.layers, strict=True):
        c = nn.Conv2d(spec.in_channels, spec.out_channels, spec.kernel, padding=spec.kernel // 2)
        with torch.no_grad():
            c.weight.copy_(conv.weight)
            c.bias.copy_(conv.bias)
        mods.append(c)
        if spec.activation is not None:
            mods.append(TORCH_ACTIVATIONS[spec.activation])
    return nn.Sequential(*mods)


CASES = [
    ([(7, 16, 3, "relu"), (16, 16, 3, "relu"), (16, 3, 3, None)], True),
    ([(9, 8, 5, "silu"), (8, 8, 1, "gelu"), (8, 3, 3, None)], True),
    ([(5, 6, 3, "tanh"), (6, 6, 3, "elu"), (6, 6, 3, "leaky_relu"), (6, 3, 1, "softplus")], False),
]


@pytest.mark.parametrize(("layers", "residual"), CASES)
def test_forward_matches_a_plain_conv2d_stack(layers, residual) -> None:
    cnn = random_cnn(layers, residual, seed=len(layers))
    ref = torch_stack(cnn)
    x = torch.randn(2, layers[0][0], 23, 17, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        want = ref(x) + (x[:, :3] if residual else 0.0)
        got = cnn(x)
    assert got.shape == (2, 3, 23, 17)
    torch.testing.assert_close(got, want, rtol=1e-5, atol=1e-5)


def test_refine_is_the_forward_on_an_hwc_image_clamped() -> None:
    cnn = random_cnn(CASES[0][0], True, seed=4)
    image = np.random.default_rng(2).uniform(-0.2, 1.2, (31, 29, 7)).astype(np.float32)
    out = cnn.refine(image)
    x = torch.from_numpy(image).permute(2, 0, 1)[None]
    with torch.no_grad():
        want = (torch_stack(cnn)(x) + x[:, :3])[0]
    want = want.clamp(0.0, 1.0).permute(1, 2, 0).numpy()
    assert out.shape == (31, 29, 3) and out.dtype == np.float32
    np.testing.assert_allclose(out, want, atol=1e-5)
    assert out.min() >= 0.0 and out.max() <= 1.0


def test_a_traced_copy_runs_the_same() -> None:
    cnn = random_cnn(CASES[1][0], True, seed=5).eval()
    traced = torch.jit.trace(cnn, torch.zeros(1, 9, 16, 16))
    image = np.random.default_rng(3).uniform(0, 1, (40, 24, 9)).astype(np.float32)  # another size than traced
    np.testing.assert_allclose(run_cnn(traced, image, torch.device("cpu")), cnn.refine(image), atol=1e-6)


def test_weights_survive_the_file(tmp_path) -> None:
    avatar = make_synthetic_avatar(50, latent_dim=4, with_cnn=True, seed=9)
    save_avatar(avatar, tmp_path / "a.npga")
    back = read_avatar(tmp_path / "a.npga").cnn
    assert back is not None and back.config.to_json() == avatar.cnn.config.to_json()
    x = torch.randn(1, 7, 12, 12)
    with torch.no_grad():
        torch.testing.assert_close(back(x), torch_stack(avatar.cnn)(x) + x[:, :3], rtol=1e-5, atol=1e-5)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_on_a_gpu_it_matches_the_cpu() -> None:
    cnn = random_cnn(CASES[0][0], True, seed=6)
    image = np.random.default_rng(4).uniform(0, 1, (64, 48, 7)).astype(np.float32)
    cpu = cnn.refine(image)
    gpu = cnn.to("cuda").refine(image)
    assert cnn.device.type == "cuda"
    np.testing.assert_allclose(gpu, cpu, atol=1e-4)
