"""compensation.training.conv_grad: the NCHW weight gradient of wide convolutions equals autograd's
own, in both layouts; narrow and transposed ones are left alone; exit restores."""
from __future__ import annotations

from contextlib import nullcontext

import pytest
import torch

from compensation.methods.compennet import CompenNet
from compensation.training.conv_grad import nchw_weight_gradients


def gradients(module: torch.nn.Module, x: torch.Tensor, patched: bool) -> list[torch.Tensor]:
    x = x.detach().clone().requires_grad_()
    module.zero_grad(set_to_none=True)
    with nchw_weight_gradients(module) if patched else nullcontext():
        out = module(x)
        (out * torch.linspace(-1, 1, out.numel()).view_as(out)).sum().backward()
    return [x.grad, module.weight.grad, module.bias.grad]


@pytest.mark.parametrize("layout", [torch.contiguous_format, torch.channels_last])
@pytest.mark.parametrize("make", [
    lambda: torch.nn.Conv2d(64, 16, 3, 1, 1),
    lambda: torch.nn.Conv2d(64, 16, 3, 2, 1),
    lambda: torch.nn.Conv2d(96, 8, 1),
], ids=["3x3", "3x3 stride 2", "1x1"])
def test_gradients_equal_autograds(make, layout):
    torch.manual_seed(0)
    module = make().to(memory_format=layout)
    x = torch.rand(3, module.in_channels, 10, 14).contiguous(memory_format=layout)
    reference = [g.clone() for g in gradients(module.double(), x.double(), patched=False)]
    module.float()
    with nchw_weight_gradients(module) as changed:
        assert changed == 1
        out = module(x)
    assert out.shape == module(x).shape
    plain = gradients(module, x, patched=False)
    for got, own, want in zip(gradients(module, x, patched=True), plain, reference):
        # float32 against float64: within a few times autograd's own float32 rounding
        scale = want.abs().max().item()
        own_error = (own.double() - want).abs().max().item()
        assert (got.double() - want).abs().max().item() <= 4 * own_error + 1e-6 * scale


def test_narrow_layers_are_left_alone_and_exit_restores():
    model = CompenNet(surface=True)
    with nchw_weight_gradients(model) as changed:
        wide = [n for n, m in model.named_modules() if "forward" in vars(m)]
    # Conv2d with at least 64 input channels: conv3-5, conv3_s, conv4_s, skipConv3
    assert changed == 6
    assert sorted(wide) == sorted(["conv3", "conv4", "conv5", "conv3_s", "conv4_s", "skipConv3"])
    assert not [n for n, m in model.named_modules() if "forward" in vars(m)]

