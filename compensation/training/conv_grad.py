"""Convolutions with a faster backward pass on the CPU, for training in the channels-last layout.

Two replacements, each a context manager that changes a model's layers while inside and restores
them on exit; forward values are the layers' own, gradients the same to float rounding
(``tests/test_conv_grad.py``). :func:`faster_backward` applies those that measured faster on the
CPU it runs on; ``benchmarks/train.py`` times it.

* :func:`conv_transpose_gradients`: a transposed convolution's backward pass is the strided
  convolution that it transposes: its input gradient is that convolution of the output gradient,
  its weight gradient that convolution's weight gradient with input and output swapped. On the
  channels-last data oneDNN runs those near twice as fast as its own transposed-convolution
  backward (CompenNet's transConv2, 128², batch 16: 31.8 → 18.3 ms on an AVX-512 CPU; no faster
  in the default layout), and the input and weight gradients come out bit for bit the same.
* :func:`nchw_weight_gradients`: oneDNN's convolution forward and input gradient are fastest in
  the channels-last layout that training keeps the network in; its weight gradient in that
  layout took 2.8-4.6× the forward on an AVX2 CPU, against 1.1-1.2× in the default (NCHW)
  layout, but 1.2-1.4× on an AVX-512 CPU, where the NCHW copies made it slower (whole step
  5-7 % slower). So only on AVX2 (:data:`NCHW_WEIGHT_GRADIENT_CPUS`) do the wide convolutions
  compute their weight and bias gradients from NCHW copies of the input and of the output
  gradient; forward and input gradient stay channels-last.

Under bf16 autocast a layer's forward computes in bf16 from its float32 weight; the replacements
take their backward in the output gradient's type too and return float32 weight and bias
gradients, as the layers' own backward does.
"""
from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, ExitStack, contextmanager

import torch
import torch.nn.functional as F

NCHW_WEIGHT_GRADIENT_CPUS = frozenset({"AVX2"})
"""CPU capabilities (``torch.backends.cpu.get_cpu_capability()``) on which :func:`faster_backward`
takes the NCHW weight gradients (measured faster on AVX2, slower on AVX-512; elsewhere not
measured, so left as torch computes them)."""

MIN_CHANNELS = 64
"""Convolutions with at least this many input channels get the NCHW weight gradient (CompenNet's
conv3-conv5, conv3_s, conv4_s, skipConv3): the layers where the AVX2 profile found the
channels-last weight gradient slow; on narrower ones the two layout copies weigh more
(``benchmarks/results/train/README.md``)."""

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
        x, w = x.to(grad.dtype), weight.to(grad.dtype)  # autocast's computing type
        grad_x = None
        if ctx.needs_input_grad[0]:
            grad_x = _backward(grad, x, w, None, *fixed, [True, False, False])[0]
        _, grad_w, grad_b = _backward(grad.contiguous(), x.contiguous(), w.contiguous(),
                                      [weight.shape[0]] if has_bias else None, *fixed,
                                      [False, True, has_bias])
        return (grad_x, grad_w.to(weight.dtype), None if grad_b is None else grad_b.to(weight.dtype),
                None, None)


class _ConvTranspose2d(torch.autograd.Function):
    """``F.conv_transpose2d`` (one group) with its backward pass as the strided convolution that
    it transposes: input gradient ``conv2d(grad, weight)``, weight gradient that convolution's
    weight gradient with input and output swapped."""

    @staticmethod
    def forward(ctx, x, weight, bias, stride, padding, output_padding, dilation):
        ctx.save_for_backward(x, weight)
        ctx.geometry = (stride, padding, dilation)
        return F.conv_transpose2d(x, weight, bias, stride, padding, output_padding, 1, dilation)

    @staticmethod
    def backward(ctx, grad):
        x, weight = ctx.saved_tensors
        stride, padding, dilation = ctx.geometry
        x, w = x.to(grad.dtype), weight.to(grad.dtype)  # autocast's computing type
        grad_x = grad_w = grad_b = None
        if ctx.needs_input_grad[0]:
            grad_x = F.conv2d(grad, w, None, stride, padding, dilation)
        if ctx.needs_input_grad[1]:
            grad_w = _backward(x, grad, w, None, stride, padding, dilation, False, [0, 0], 1,
                               [False, True, False])[1].to(weight.dtype)
        if ctx.needs_input_grad[2]:
            grad_b = grad.sum((0, 2, 3), dtype=weight.dtype)
        return grad_x, grad_w, grad_b, None, None, None, None


def _wide_conv(module: torch.nn.Module) -> bool:
    """A plain wide Conv2d (zero padding, dilation 1, one group) whose gradient we replace."""
    return (type(module) is torch.nn.Conv2d and module.in_channels >= MIN_CHANNELS
            and module.padding_mode == "zeros" and module.groups == 1
            and tuple(module.dilation) == (1, 1) and isinstance(module.padding, tuple))


def _plain_transpose(module: torch.nn.Module) -> bool:
    """A ConvTranspose2d with one group and an output padding below its stride (a larger one,
    allowed with dilation, adds rows that no strided convolution of the output maps back)."""
    return (type(module) is torch.nn.ConvTranspose2d and module.groups == 1
            and all(p < s for p, s in zip(module.output_padding, module.stride)))


def _conv_forward(self: torch.nn.Conv2d, x: torch.Tensor) -> torch.Tensor:
    if x.dim() != 4:  # an unbatched image: the layer's own code
        return type(self).forward(self, x)
    return _Conv2d.apply(x, self.weight, self.bias, list(self.stride), list(self.padding))


def _transpose_forward(self: torch.nn.ConvTranspose2d, x: torch.Tensor,
                       output_size: list[int] | None = None) -> torch.Tensor:
    if output_size is not None or x.dim() != 4:  # output padding from the size, or an unbatched
        return type(self).forward(self, x, output_size)  # image: the layer's own code
    return _ConvTranspose2d.apply(x, self.weight, self.bias, list(self.stride), list(self.padding),
                                  list(self.output_padding), list(self.dilation))


@contextmanager
def _patched(model: torch.nn.Module, applies: Callable[[torch.nn.Module], bool],
             forward: Callable) -> Iterator[int]:
    """While inside, the modules of ``model`` that ``applies`` accepts run ``forward``; a module
    that already has a ``forward`` of its own (say, from an enclosing block) is left as it is."""
    changed = [m for m in model.modules() if applies(m) and "forward" not in vars(m)]
    for m in changed:
        m.forward = forward.__get__(m)
    try:
        yield len(changed)
    finally:
        for m in changed:
            del m.forward


def nchw_weight_gradients(model: torch.nn.Module) -> AbstractContextManager[int]:
    """While inside, the wide plain convolutions of ``model`` take their weight gradient in NCHW.

    Parameters
    ----------
    model : torch.nn.Module
        Its ``Conv2d`` modules with at least :data:`MIN_CHANNELS` input channels are changed
        (their instance ``forward``), and restored on exit however the block ends; modules that
        already have an instance ``forward`` are left alone.

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


def conv_transpose_gradients(model: torch.nn.Module) -> AbstractContextManager[int]:
    """While inside, ``model``'s transposed convolutions take their backward pass as the strided
    convolution that they transpose.

    Parameters
    ----------
    model : torch.nn.Module
        Its ``ConvTranspose2d`` modules with one group and an output padding below the stride
        are changed (their instance ``forward``), and restored on exit however the block ends.
        A call with an explicit ``output_size``, or on an unbatched (C, H, W) image, runs the
        layer's own forward and backward.

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
    >>> with conv_transpose_gradients(up) as changed:
    ...     up(x).square().sum().backward()
    >>> got = x.grad, up.weight.grad, up.bias.grad
    >>> changed, all(torch.allclose(g, r, rtol=1e-4, atol=1e-5) for g, r in zip(got, reference))
    (1, True)
    """
    return _patched(model, _plain_transpose, _transpose_forward)


def nchw_weight_gradients_pay() -> bool:
    """Whether this CPU's capability is one of :data:`NCHW_WEIGHT_GRADIENT_CPUS`."""
    return torch.backends.cpu.get_cpu_capability() in NCHW_WEIGHT_GRADIENT_CPUS


@contextmanager
def faster_backward(model: torch.nn.Module, nchw: bool | None = None) -> Iterator[tuple[int, int]]:
    """While inside, ``model`` takes the backward replacements that measured faster on this CPU
    in the channels-last layout that training uses: :func:`conv_transpose_gradients` always,
    :func:`nchw_weight_gradients` where the CPU's capability is in
    :data:`NCHW_WEIGHT_GRADIENT_CPUS`.

    Parameters
    ----------
    model : torch.nn.Module
        The network to change while inside.
    nchw : bool, optional
        Take the NCHW weight gradients (True) or not (False) whatever the CPU; None follows
        :func:`nchw_weight_gradients_pay` (``benchmarks/train.py --nchw-ab`` times both).

    Yields
    ------
    tuple of int
        How many wide convolutions and how many transposed convolutions were changed.

    Examples
    --------
    >>> from compensation.methods.compennet import CompenNet
    >>> with faster_backward(CompenNet()) as changed:
    ...     changed == (6 if nchw_weight_gradients_pay() else 0, 2)
    True
    >>> with faster_backward(CompenNet(), nchw=True) as changed:
    ...     changed
    (6, 2)
    """
    with ExitStack() as stack:
        transposed = stack.enter_context(conv_transpose_gradients(model))
        pays = nchw_weight_gradients_pay() if nchw is None else nchw
        wide = stack.enter_context(nchw_weight_gradients(model)) if pays else 0
        yield wide, transposed
