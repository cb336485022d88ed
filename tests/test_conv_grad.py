"""compensation.training.conv_grad: the NCHW weight gradient of wide convolutions and the
transposed convolutions' backward as strided convolutions equal autograd's own, in both layouts;
other layers are left alone; exit restores."""
from __future__ import annotations

from contextlib import nullcontext

import pytest
import torch

from compensation.methods.compennet import CompenNet
from compensation.training.conv_grad import (faster_backward, nchw_weight_gradients,
                                              conv_transpose_gradients)


def gradients(module: torch.nn.Module, x: torch.Tensor, patch) -> list[torch.Tensor]:
    x = x.detach().clone().requires_grad_()
    module.zero_grad(set_to_none=True)
    with patch(module) if patch else nullcontext():
        out = module(x)
        (out * torch.linspace(-1, 1, out.numel()).view_as(out)).sum().backward()
    return [x.grad, module.weight.grad, module.bias.grad]


def check_against_float64(module: torch.nn.Module, x: torch.Tensor, patch) -> None:
    """``patch``'s gradients in float32 are as close to float64 autograd as autograd's own."""
    reference = [g.clone() for g in gradients(module.double(), x.double(), patch=None)]
    module.float()
    with patch(module) as changed:
        assert changed == 1
        out = module(x)
    assert type(out.grad_fn).__name__ in ("_Conv2dBackward", "_ConvTranspose2dBackward")
    assert torch.equal(out, module(x))  # the forward is the layer's own
    plain = gradients(module, x, patch=None)
    for got, own, want in zip(gradients(module, x, patch), plain, reference):
        assert got.shape == want.shape
        # float32 against float64: within a few times autograd's own float32 rounding
        scale = want.abs().max().item()
        own_error = (own.double() - want).abs().max().item()
        assert (got.double() - want).abs().max().item() <= 4 * own_error + 1e-6 * scale


CASES = [  # (layer, replacement), ids below
    (lambda: torch.nn.Conv2d(64, 16, 3, 1, 1), nchw_weight_gradients),
    (lambda: torch.nn.Conv2d(64, 16, 3, 2, 1), nchw_weight_gradients),
    (lambda: torch.nn.Conv2d(96, 8, 1), nchw_weight_gradients),
    (lambda: torch.nn.ConvTranspose2d(16, 8, 2, 2), conv_transpose_gradients),
    (lambda: torch.nn.ConvTranspose2d(6, 5, (2, 3), (2, 3)), conv_transpose_gradients),
    (lambda: torch.nn.ConvTranspose2d(8, 4, 4, 2, 1), conv_transpose_gradients),
    (lambda: torch.nn.ConvTranspose2d(4, 6, 3, 2, 1, output_padding=1), conv_transpose_gradients),
    (lambda: torch.nn.ConvTranspose2d(4, 3, 3, 1, 2, dilation=2), conv_transpose_gradients),
    (lambda: torch.nn.ConvTranspose2d(3, 2, (1, 2), (3, 1), (0, 3), output_padding=(2, 0)),
     conv_transpose_gradients),
]
IDS = ["conv 3x3", "conv 3x3 stride 2", "conv 1x1", "transposed 2x2 stride 2",
       "transposed 2x3 stride 2x3", "transposed 4x4 stride 2 pad 1", "transposed output padding",
       "transposed dilation 2", "transposed stride > kernel, padding > kernel"]


@pytest.mark.parametrize("layout", [torch.contiguous_format, torch.channels_last])
@pytest.mark.parametrize("make, patch", CASES, ids=IDS)
def test_gradients_equal_autograds(make, patch, layout):
    torch.manual_seed(0)
    module = make().to(memory_format=layout)
    x = torch.rand(3, module.in_channels, 10, 14).contiguous(memory_format=layout)
    check_against_float64(module, x, patch)


@pytest.mark.parametrize("layout", [torch.contiguous_format, torch.channels_last])
def test_conv_transpose_gradients_are_onednns_own_bit_for_bit(layout):
    """Input and weight gradient: the same oneDNN arithmetic as torch's own backward."""
    torch.manual_seed(2)
    module = torch.nn.ConvTranspose2d(64, 32, 2, 2).to(memory_format=layout)
    x = torch.rand(4, 64, 16, 16).contiguous(memory_format=layout)
    plain = gradients(module, x, patch=None)
    got = gradients(module, x, conv_transpose_gradients)
    assert torch.equal(got[0], plain[0]) and torch.equal(got[1], plain[1])


def test_conv_transpose_without_bias_or_input_gradient():
    torch.manual_seed(1)
    module = torch.nn.ConvTranspose2d(8, 4, 2, 2, bias=False)
    x = torch.rand(2, 8, 3, 4)  # no gradient wanted for the input
    module(x).square().sum().backward()
    want = module.weight.grad.clone()
    module.weight.grad = None
    with conv_transpose_gradients(module):
        module(x).square().sum().backward()
    assert torch.allclose(module.weight.grad, want, rtol=1e-5, atol=1e-6)


def test_unbatched_images_run_the_layers_own():
    torch.manual_seed(3)
    for module in (torch.nn.Conv2d(64, 4, 3, padding=1), torch.nn.ConvTranspose2d(4, 2, 2, 2)):
        x = torch.rand(module.in_channels, 6, 6, requires_grad=True)
        module(x).square().sum().backward()
        want = x.grad.clone(), module.weight.grad.clone()
        x.grad = module.weight.grad = module.bias.grad = None
        with nchw_weight_gradients(module), conv_transpose_gradients(module):
            module(x).square().sum().backward()
        assert torch.allclose(x.grad, want[0]) and torch.allclose(module.weight.grad, want[1])


def test_explicit_output_size_runs_the_layers_own():
    module = torch.nn.ConvTranspose2d(4, 2, 2, 2)
    x = torch.rand(1, 4, 3, 3)
    with conv_transpose_gradients(module):
        assert module(x, output_size=[7, 7]).shape == (1, 2, 7, 7)  # output padding 1
        assert module(x).shape == (1, 2, 6, 6)


def test_output_padding_from_dilation_is_left_alone():
    """An output padding at or above the stride (allowed with dilation) keeps the layer's own
    backward: the strided convolution's output would have more rows than the input."""
    module = torch.nn.ConvTranspose2d(1, 1, 3, stride=1, dilation=2, output_padding=1)
    x = torch.rand(1, 1, 4, 4, requires_grad=True)
    with conv_transpose_gradients(module) as changed:
        module(x).sum().backward()
    assert changed == 0 and x.grad.shape == x.shape


def test_nested_blocks_and_own_forwards_are_kept():
    own = torch.nn.ConvTranspose2d(2, 2, 2, 2)
    own.forward = lambda x: x  # an instance forward of the caller's
    model = torch.nn.Sequential(torch.nn.ConvTranspose2d(2, 2, 2, 2), own)
    with conv_transpose_gradients(model) as outer:
        with conv_transpose_gradients(model) as inner:
            assert (outer, inner) == (1, 0)
        assert "forward" in vars(model[0])  # the inner exit left the outer block's change
    assert "forward" not in vars(model[0]) and vars(own)["forward"] is not None
    assert torch.equal(own(torch.ones(1)), torch.ones(1))


def test_other_layers_are_left_alone_and_exit_restores():
    model = CompenNet(surface=True)
    model.extra = torch.nn.ConvTranspose2d(4, 4, 2, 2, groups=2)
    patched = lambda: sorted(n for n, m in model.named_modules() if "forward" in vars(m))
    with nchw_weight_gradients(model) as wide, conv_transpose_gradients(model) as transposed:
        # Conv2d with at least 64 input channels: conv3-5, conv3_s, conv4_s, skipConv3
        assert (wide, transposed) == (6, 2)
        assert patched() == sorted(["conv3", "conv4", "conv5", "conv3_s", "conv4_s", "skipConv3",
                                    "transConv1", "transConv2"])
    assert not patched()


@pytest.mark.parametrize("capability, wide", [("AVX2", 6), ("AVX512", 0), ("DEFAULT", 0)])
def test_faster_backward_takes_nchw_weight_gradients_on_avx2_only(monkeypatch, capability, wide):
    monkeypatch.setattr(torch.backends.cpu, "get_cpu_capability", lambda: capability)
    model = CompenNet(surface=True)
    with faster_backward(model) as changed:
        assert changed == (wide, 2)
        assert ("forward" in vars(model.conv4)) == bool(wide)
        assert "forward" in vars(model.transConv2)
    assert not [n for n, m in model.named_modules() if "forward" in vars(m)]


@pytest.mark.parametrize("make, patch", [CASES[0], CASES[3], CASES[5]], ids=[IDS[0], IDS[3], IDS[5]])
def test_gradients_under_bf16_autocast_are_the_layers_own(make, patch):
    """Under bf16 autocast (``procam train --amp``) the replacements compute in bf16 as the
    layers do and hand back float32 gradients: input and weight gradients bit for bit the layers'
    own under autocast, the bias gradient (summed in float32) within 0.1 % of it; a float32
    backward would differ from them by over 0.1 %."""
    torch.manual_seed(4)
    module = make().to(memory_format=torch.channels_last)
    x = torch.rand(3, module.in_channels, 10, 14).contiguous(memory_format=torch.channels_last)

    def autocast_gradients(patch):
        with torch.autocast("cpu", dtype=torch.bfloat16):
            return [g.clone() for g in gradients(module, x, patch)]

    own, got = autocast_gradients(None), autocast_gradients(patch)
    full = gradients(module, x, None)
    assert all(g.dtype == torch.float32 for g in got)
    assert torch.equal(got[0], own[0]) and torch.equal(got[1], own[1])
    assert (got[2] - own[2]).abs().max() <= 1e-3 * own[2].abs().max()
    assert (full[1] - own[1]).abs().max() > 1e-3 * own[1].abs().max()  # autocast computed in bf16
