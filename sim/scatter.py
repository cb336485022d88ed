"""Wide scatter: a fraction of an image's light spread by a wide Gaussian, cheaply and linearly.

Both the projector's flare (:mod:`sim.projector.flare`) and the camera's veiling glare
(:mod:`sim.camera.glare`) scatter a small fraction of each pixel's light over a large part of the
image: ``(1 - fraction) x + fraction (G * x)`` for a Gaussian ``G`` of a standard deviation of tens
to hundreds of pixels (:func:`veil`). A direct convolution with such a kernel costs far too much
per frame, so the wide blur (:func:`wide_blur`) is computed on a coarser grid: the image is
averaged over ``s x s`` blocks (``s`` the integer :func:`coarse_factor`, the image padded with
zeros to whole blocks), blurred there by ``sigma / s`` coarse pixels and enlarged back bilinearly.
Each step is linear, so the result is linear in the image. Averaging over blocks and the bilinear
enlargement keep the total exactly; the coarse blur drops the light that spreads past the image's
edge (the image is taken as dark outside), which is lost. The approximation: the block average
and the bilinear enlargement widen the kernel a little (a variance of about ``s**2 / 4`` pixels²
per axis, 0.4 % of ``sigma**2``), and a point's scatter is centred on its block's centre, up to
``s / 2 <= sigma / 16`` pixels from the point itself.
"""
from __future__ import annotations

import math

import cv2
import numpy as np

COARSE_SIGMA = 8.0
"""Standard deviation (coarse pixels) the wide blur keeps on its coarse grid: ``s`` is the largest
integer with ``sigma / s >= COARSE_SIGMA``."""


def coarse_factor(sigma: float) -> int:
    """The block size ``s`` :func:`wide_blur` averages over for a Gaussian of ``sigma`` pixels.

    Examples
    --------
    >>> coarse_factor(3.0), coarse_factor(80.0), coarse_factor(87.0)
    (1, 10, 10)
    """
    return max(1, int(sigma // COARSE_SIGMA))


def wide_blur(image: np.ndarray, sigma: float) -> np.ndarray:
    """The image convolved with a normalised Gaussian of ``sigma`` pixels, on a coarse grid (see
    the module docstring); dark outside the image.

    Parameters
    ----------
    image : numpy.ndarray
        float32 (H, W, C), C at most 4.
    sigma : float
        Standard deviation in pixels, > 0.

    Returns
    -------
    numpy.ndarray
        float32 (H, W, C).

    Examples
    --------
    >>> x = np.zeros((200, 200, 1), np.float32); x[100, 100] = 1.0
    >>> round(float(wide_blur(x, 20.0).sum()), 5)
    1.0
    """
    h, w = image.shape[:2]
    s = coarse_factor(sigma)
    hc, wc = -(-h // s), -(-w // s)
    img = np.ascontiguousarray(image, np.float32)
    if s > 1:
        img = cv2.copyMakeBorder(img, 0, hc * s - h, 0, wc * s - w, cv2.BORDER_CONSTANT, value=0.0)
        img = cv2.resize(img, (wc, hc), interpolation=cv2.INTER_AREA)
    sc = sigma / s
    k = 2 * int(math.ceil(4.0 * sc)) + 1
    img = cv2.GaussianBlur(img, (k, k), sc, sigmaY=sc, borderType=cv2.BORDER_CONSTANT)
    if s > 1:
        img = cv2.resize(img, (wc * s, hc * s), interpolation=cv2.INTER_LINEAR)[:h, :w]
    return img.reshape(image.shape)


def veil(image: np.ndarray, fraction: float, sigma: float) -> np.ndarray:
    """``(1 - fraction) image + fraction (G * image)``: each pixel keeps ``1 - fraction`` of its
    light and scatters the rest by the Gaussian ``G`` of ``sigma`` pixels (:func:`wide_blur`).

    Parameters
    ----------
    image : numpy.ndarray
        float32 (H, W, C) linear light.
    fraction : float
        Fraction of the light scattered, in [0, 1].
    sigma : float
        Standard deviation of the scatter in pixels, > 0.

    Returns
    -------
    numpy.ndarray
        float32 (H, W, C).

    Examples
    --------
    >>> x = np.zeros((64, 64, 1), np.float32); x[32, 32] = 1.0
    >>> y = veil(x, 0.1, 8.0)
    >>> round(float(y[32, 32, 0]), 3), round(float(y.sum()), 4)
    (0.9, 1.0)
    """
    img = np.asarray(image, np.float32)
    return (1.0 - fraction) * img + np.float32(fraction) * wide_blur(img, sigma)
