"""Convolutions with a faster backward pass on the CPU, for training in the channels-last layout.

Two replacements, each a context manager that changes a model's layers while inside and restores
them on exit; forward values are the layers' own, gradients the same to float rounding
(``tests/test_conv_grad.py``). :func:`faster_backward` applies those that measured faster on the
CPU it runs on; ``benchmarks/train.py`` times it.

* :func:`space_to_depth_gradients`: a transposed convolution whose kernel equals its stride
  (CompenNet's 2×2, stride 2) writes each input pixel to its own k×k block of the output, so its
  backward pass is a 1×1 convolution of the output gradient rearranged into k·k·C channels (space
  to depth). oneDNN runs that 1×1 convolution near its matrix-product speed, where its own
  transposed-convolution backward runs at a fraction of it (CompenNet's transConv2 at 128²,
  batch 16: 22.9 → 15.1 ms on an AVX-512 CPU).
* :func:`nchw_weight_gradients`: oneDNN's convolution forward and input gradient are fastest in
  the channels-last layout that training keeps the network in; its weight gradient in that
  layout took 2.8-4.6× the forward on an AVX2 CPU, against 1.1-1.2× in the default (NCHW)
  layout, but 1.2-1.4× on an AVX-512 CPU, where the NCHW copies made it slower (whole step
  5-7 % slower). So only on AVX2 (:data:`NCHW_WEIGHT_GRADIENT_CPUS`) do the wide convolutions
  compute their weight and bias gradients from NCHW copies of the input and of the output
  gradient; forward and input gradient stay channels-last.
"""
from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager

import torch
import torch.nn.functional as F

NCHW_WEIGHT_GRADIENT_CPUS = frozenset({"AVX2"})
"""CPU capabilities (``torch.backends.cpu.get_cpu_capability()``) on which :func:`faster_backward`
takes the NCHW weight gradients (measured faster on AVX2, slower on AVX-512; elsewhere not
measured, so left as torch computes them)."""

MIN_CHANNELS = 64
"""Convolutions with at least this many input channels get the NCHW weight gradient: on narrower
ones the two layout copies cost more than they save (``benchmarks/train.py``)."""

_backward = torch.ops.aten.convolution_backward


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
        fixed = (stride, padding, [1, 1], False, [0, 0], 1)
        grad_x = None
        if ctx.needs_input_grad[0]:
            grad_x = _backward(grad, x, weight, None, *fixed, [True, False, False])[0]
        _, grad_w, grad_b = _backward(grad.contiguous(), x.contiguous(), weight.contiguous(),
                                      [weight.shape[0]] if has_bias else None, *fixed,
                                      [False, True, has_bias])
        return grad_x, grad_w, grad_b, None, None


def space_to_depth(t: torch.Tensor, kh: int, kw: int) -> torch.Tensor:
    """(N, C, H·kh, W·kw) → (N, kh·kw·C, H, W): channel ``(a·kw + b)·C + c`` holds
    ``t[n, c, i·kh + a, j·kw + b]`` at (i, j); the result is in the channels-last layout.

    Examples
    --------
    >>> t = torch.arange(2 * 4 * 6.).view(1, 2, 4, 6)
    >>> u = space_to_depth(t, 2, 3)
    >>> u.shape, u.is_contiguous(memory_format=torch.channels_last)
    (torch.Size([1, 12, 2, 2]), True)
    >>> a, b, c, i, j = 1, 2, 1, 1, 0
    >>> bool(u[0, (a * 3 + b) * 2 + c, i, j] == t[0, c, i * 2 + a, j * 3 + b])
    True
    """
    n, c, h, w = t.shape
    blocks = t.permute(0, 2, 3, 1).reshape(n, h // kh, kh, w // kw, kw * c)
    return (blocks.permute(0, 1, 3, 2, 4).contiguous()
            .view(n, h // kh, w // kw, kh * kw * c).permute(0, 3, 1, 2))


class _ConvTransposeBlocks(torch.autograd.Function):
    """``F.conv_transpose2d`` with kernel = stride (no padding, dilation 1, one group), its backward
    as a 1×1 convolution of the space-to-depth output gradient."""

    @staticmethod
    def forward(ctx, x, weight, bias):
        ctx.save_for_backward(x, weight)
        ctx.has_bias = bias is not None
        return F.conv_transpose2d(x, weight, bias, tuple(weight.shape[2:]))

    @staticmethod
    def backward(ctx, grad):
        x, weight = ctx.saved_tensors
        c_in, c_out, kh, kw = weight.shape
        u = space_to_depth(grad, kh, kw)
        # as a 1×1 convolution x → u: weight (kh·kw·c_out, c_in), rows in u's channel order
        w_1x1 = weight.permute(2, 3, 1, 0).reshape(kh * kw * c_out, c_in, 1, 1)
        grad_x = grad_w = grad_b = None
        if ctx.needs_input_grad[0]:
            grad_x = _backward(u, x, w_1x1, None, [1, 1], [0, 0], [1, 1], False, [0, 0], 1,
                               [True, False, False])[0]
        if ctx.needs_input_grad[1]:
            g = _backward(u, x, w_1x1, None, [1, 1], [0, 0], [1, 1], False, [0, 0], 1,
                          [False, True, False])[1]
            grad_w = g.view(kh, kw, c_out, c_in).permute(3, 2, 0, 1)
        if ctx.has_bias and ctx.needs_input_grad[2]:
            grad_b = grad.sum((0, 2, 3))
        return grad_x, grad_w, grad_b


def _wide_conv(module: torch.nn.Module) -> bool:
    """A plain wide Conv2d (zero padding, dilation 1, one group) whose gradient we replace."""
    return (type(module) is torch.nn.Conv2d and module.in_channels >= MIN_CHANNELS
            and module.padding_mode == "zeros" and module.groups == 1
            and tuple(module.dilation) == (1, 1) and isinstance(module.padding, tuple))


def _block_transpose(module: torch.nn.Module) -> bool:
    """A ConvTranspose2d whose kernel equals its stride (no padding, dilation 1, one group)."""
    return (type(module) is torch.nn.ConvTranspose2d
            and tuple(module.kernel_size) == tuple(module.stride)
            and tuple(module.padding) == (0, 0) and tuple(module.output_padding) == (0, 0)
            and tuple(module.dilation) == (1, 1) and module.groups == 1
            and module.padding_mode == "zeros")


def _conv_forward(self: torch.nn.Conv2d, x: torch.Tensor) -> torch.Tensor:
    return _Conv2d.apply(x, self.weight, self.bias, list(self.stride), list(self.padding))


def _transpose_forward(self: torch.nn.ConvTranspose2d, x: torch.Tensor,
                       output_size: list[int] | None = None) -> torch.Tensor:
    if output_size is not None:  # an explicit size may ask for output padding: the layer's own
        return type(self).forward(self, x, output_size)
    return _ConvTransposeBlocks.apply(x, self.weight, self.bias)


@contextmanager
def _patched(model: torch.nn.Module, applies: Callable[[torch.nn.Module], bool],
             forward: Callable) -> Iterator[int]:
    """While inside, the modules of ``model`` that ``applies`` accepts run ``forward``."""
    changed = [m for m in model.modules() if applies(m)]
    for m in changed:
        m.forward = forward.__get__(m)
    try:
        yield len(changed)
    finally:
        for m in changed:
            del m.forward


def nchw_weight_gradients(model: torch.nn.Module):
    """While inside, the wide plain convolutions of ``model`` take their weight gradient in NCHW.

    Parameters
    ----------
    model : torch.nn.Module
        Its ``Conv2d`` modules with at least :data:`MIN_CHANNELS` input channels are changed
        (their instance ``forward``), and restored on exit however the block ends.

    Returns
    -------
    context manager yielding int
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
    return _patched(model, _wide_conv, _conv_forward)


def space_to_depth_gradients(model: torch.nn.Module):
    """While inside, ``model``'s transposed convolutions with kernel = stride take their backward
    pass as 1×1 convolutions of the space-to-depth output gradient.

    Parameters
    ----------
    model : torch.nn.Module
        Its ``ConvTranspose2d`` modules with kernel size equal to the stride, no padding or output
        padding, dilation 1 and one group are changed (their instance ``forward``), and restored
        on exit however the block ends. A call with an explicit ``output_size`` runs the layer's
        own forward and backward.

    Returns
    -------
    context manager yielding int
        How many transposed convolutions were changed.

    Examples
    --------
    >>> up = torch.nn.ConvTranspose2d(8, 4, 2, 2)
    >>> x = torch.rand(2, 8, 5, 6, requires_grad=True)
    >>> up(x).square().sum().backward()
    >>> reference = x.grad.clone(), up.weight.grad.clone(), up.bias.grad.clone()
    >>> x.grad = up.weight.grad = up.bias.grad = None
    >>> with space_to_depth_gradients(up) as changed:
    ...     up(x).square().sum().backward()
    >>> got = x.grad, up.weight.grad, up.bias.grad
    >>> changed, all(torch.allclose(g, r, rtol=1e-4, atol=1e-5) for g, r in zip(got, reference))
    (1, True)
    """
    return _patched(model, _block_transpose, _transpose_forward)


def nchw_weight_gradients_pay() -> bool:
    """Whether this CPU's capability is one of :data:`NCHW_WEIGHT_GRADIENT_CPUS`."""
    return torch.backends.cpu.get_cpu_capability() in NCHW_WEIGHT_GRADIENT_CPUS


@contextmanager
def faster_backward(model: torch.nn.Module) -> Iterator[tuple[int, int]]:
    """While inside, ``model`` takes the backward replacements that measured faster on this CPU:
    :func:`space_to_depth_gradients` always, :func:`nchw_weight_gradients` where the CPU's
    capability is in :data:`NCHW_WEIGHT_GRADIENT_CPUS`.

    Yields
    ------
    tuple of int
        How many wide convolutions and how many transposed convolutions were changed.

    Examples
    --------
    >>> from compensation.methods.compennet import CompenNet
    >>> with faster_backward(CompenNet()) as (wide, blocks):
    ...     blocks, wide == (6 if nchw_weight_gradients_pay() else 0)
    (2, True)
    """
    with ExitStack() as stack:
        blocks = stack.enter_context(space_to_depth_gradients(model))
        wide = stack.enter_context(nchw_weight_gradients(model)) if nchw_weight_gradients_pay() else 0
        yield wide, blocks
