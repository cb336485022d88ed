"""Convolutions whose weight gradient is computed in the default memory layout, for CPU training.

oneDNN's convolution forward and input gradient are fastest in the channels-last layout that
training keeps the network in, but its weight gradient in that layout is several times slower
than in the default (NCHW) layout on the AVX2 CPUs measured by ``benchmarks/train.py``. Inside
:func:`nchw_weight_gradients` the wide convolutions of a model compute their weight and bias
gradients from NCHW copies of the input and of the output gradient; forward and input gradient
stay channels-last. The values are the same convolution's to float rounding.
"""
from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import torch
import torch.nn.functional as F

MIN_CHANNELS = 64
"""Convolutions with at least this many input channels get the NCHW weight gradient: on narrower
ones the two layout copies cost more than they save (``benchmarks/train.py``)."""


class _Conv2d(torch.autograd.Function):
    """``F.conv2d`` (dilation 1, one group) with the weight gradient taken in the NCHW layout."""

    @staticmethod
    def forward(ctx, x, weight, bias, stride, padding):
        ctx.save_for_backward(x, weight)
        ctx.geometry = (stride, padding, bias is not None)
        return F.conv2d(x, weight, bias, stride, padding)

    @staticmethod
    def backward(ctx, grad):
        x, weight = ctx.saved_tensors
        stride, padding, has_bias = ctx.geometry
        conv = torch.ops.aten.convolution_backward
        fixed = (stride, padding, [1, 1], False, [0, 0], 1)
        grad_x = None
        if ctx.needs_input_grad[0]:
            grad_x = conv(grad, x, weight, None, *fixed, [True, False, False])[0]
        _, grad_w, grad_b = conv(grad.contiguous(), x.contiguous(), weight.contiguous(),
                                 [weight.shape[0]] if has_bias else None, *fixed,
                                 [False, True, has_bias])
        return grad_x, grad_w, grad_b, None, None


def _applies(module: torch.nn.Module) -> bool:
    """A plain wide Conv2d (zero padding, dilation 1, one group) whose gradient we replace."""
    return (type(module) is torch.nn.Conv2d and module.in_channels >= MIN_CHANNELS
            and module.padding_mode == "zeros" and module.groups == 1
            and tuple(module.dilation) == (1, 1) and isinstance(module.padding, tuple))


def _forward(self: torch.nn.Conv2d, x: torch.Tensor) -> torch.Tensor:
    return _Conv2d.apply(x, self.weight, self.bias, list(self.stride), list(self.padding))


@contextmanager
def nchw_weight_gradients(model: torch.nn.Module) -> Iterator[int]:
    """While inside, the wide plain convolutions of ``model`` take their weight gradient in NCHW.

    Parameters
    ----------
    model : torch.nn.Module
        Its ``Conv2d`` modules with at least :data:`MIN_CHANNELS` input channels are changed
        (their instance ``forward``), and restored on exit however the block ends.

    Yields
    ------
    int
        How many convolutions were changed.

    Examples
    --------
    >>> conv = torch.nn.Conv2d(64, 8, 3, padding=1)
    >>> x = torch.rand(2, 64, 6, 6, requires_grad=True)
    >>> conv(x).square().sum().backward()
    >>> reference = x.grad.clone(), conv.weight.grad.clone()
    >>> x.grad = conv.weight.grad = conv.bias.grad = None
    >>> with nchw_weight_gradients(conv) as changed:
    ...     conv(x).square().sum().backward()
    >>> same_x = torch.allclose(x.grad, reference[0], atol=1e-5)
    >>> changed, same_x, torch.allclose(conv.weight.grad, reference[1], rtol=1e-4)
    (1, True, True)
    """
    changed = [m for m in model.modules() if _applies(m)]
    for m in changed:
        m.forward = _forward.__get__(m)
    try:
        yield len(changed)
    finally:
        for m in changed:
            del m.forward
