"""The projector's flare: light scattered inside the projector (lens elements, the DMD's
surroundings) into a wide veil over the whole image (the stage :data:`FLARE`), and the contrasts it
sets (:func:`ansi_contrast`, :func:`full_contrast`).

Each pixel keeps ``1 - flare`` of its light and scatters ``flare`` of it by a Gaussian of
``flare_sigma`` panel widths: ``(1 - flare) x + flare (G * x)`` on the lens's padded grid, computed
cheaply on a coarse grid (:func:`sim.scatter.veil`; its approximation is described there). The
light is kept up to the padded grid's edge; what the veil spreads past it is lost.

A full-white or full-black field changes only by its scale, so the full-on/full-off contrast does
not move; a checkerboard's black squares catch the veil of the white ones, so the ANSI contrast
(4x4 checkerboard) drops: this is what sizes ``flare`` (see ``scenes/default.toml``).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from sim.options import Range, number
from sim.scatter import veil
from sim.stages import Stage

ANSI_SQUARES = 4
"""Squares of the ANSI checkerboard along each side."""
WINDOW = 1 / 16
"""Half-width of the window averaged at each point a contrast is read, as a fraction of the panel's
width and height (an eighth of a checkerboard square)."""


def _reading(light: np.ndarray, lens, x: float, y: float) -> float:
    """The mean over the channels and a small window (:data:`WINDOW`, at least a pixel) of the
    padded grid's light around panel point ``(x, y)`` (fractions of the panel's width and height)."""
    w, h = lens.panel
    p = lens.pad
    x0, x1 = (int(round(p + (x + s * WINDOW) * w)) for s in (-1, 1))
    y0, y1 = (int(round(p + (y + s * WINDOW) * h)) for s in (-1, 1))
    return float(light[y0:max(y1, y0 + 1), x0:max(x1, x0 + 1)].mean())


def ansi_contrast(emit: Callable[[np.ndarray], np.ndarray], lens) -> float:
    """The ANSI contrast of a projector: a 4x4 checkerboard over the whole panel, the mean of the
    white squares' centres over the mean of the black squares' centres.

    Parameters
    ----------
    emit : callable
        The projector's emission, a float frame (H, W, 3) in [0, 1] at the panel's resolution to
        the light on the lens's padded grid: :meth:`sim.render.Renderer.emit`, or
        :func:`sim.stages.run` of :data:`sim.projector.chain.EMISSION` with the projector's
        section and lens.
    lens : sim.projector.Lens
        The setup's lens (panel and padding).

    Returns
    -------
    float
        The contrast ratio (``:1``).
    """
    w, h = lens.panel
    row = (np.arange(h) * ANSI_SQUARES // h)[:, None]
    col = (np.arange(w) * ANSI_SQUARES // w)[None, :]
    board = ((row + col) % 2 == 0).astype(np.float32)
    light = emit(np.repeat(board[..., None], 3, axis=2))
    readings: dict[bool, list[float]] = {True: [], False: []}
    for j in range(ANSI_SQUARES):
        for i in range(ANSI_SQUARES):
            at = ((i + 0.5) / ANSI_SQUARES, (j + 0.5) / ANSI_SQUARES)
            readings[(i + j) % 2 == 0].append(_reading(light, lens, *at))
    return float(np.mean(readings[True]) / np.mean(readings[False]))


def full_contrast(emit: Callable[[np.ndarray], np.ndarray], lens) -> float:
    """The full-on/full-off contrast of a projector: the centre of a white frame over the centre of
    a black frame (``emit`` and ``lens`` as in :func:`ansi_contrast`)."""
    w, h = lens.panel
    white, black = (_reading(emit(np.full((h, w, 3), v, np.float32)), lens, 0.5, 0.5)
                    for v in (1.0, 0.0))
    return white / black


@dataclass(frozen=True)
class FlareOptions:
    """The keys of the projector's flare."""

    flare: float = number(0.0, Range(0, 0.5), "(fraction of the light)")
    """Fraction in [0, 0.5] of each pixel's light scattered into the wide veil; 0 is off."""
    flare_sigma: float = number(0.25, Range(0, 2, lo_open=True), "(fraction of the panel width)")
    """Standard deviation of the veil's Gaussian as a fraction of the panel's width, in (0, 2]."""


def _flare(light: np.ndarray, cfg, lens) -> np.ndarray:
    return veil(light, cfg.flare, cfg.flare_sigma * lens.panel[0])


FLARE = Stage("flare", FlareOptions, "light scattered inside the projector into a wide Gaussian "
              "veil (sim.scatter.veil)", _flare, optical=True, linear=True, off={"flare": 0.0})
"""The projector's flare stage."""
