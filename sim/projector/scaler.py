"""The projector's scaler: where an input frame lands on the native panel, and the frame
resampled onto it (the stage :data:`SCALER`)."""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from sim.options import boolean
from sim.stages import Stage


def frame_area(panel: tuple[int, int], frame: tuple[int, int],
               keep_aspect: bool) -> tuple[float, float, float, float]:
    """Where the scaler puts an input frame on the panel.

    With ``keep_aspect`` the frame is scaled by the largest factor that fits the panel, its size
    rounded to whole pixels keeping the panel's margins equal (so the area stays centred on whole
    pixels), the rest of the panel dark; otherwise it is stretched to the whole panel.

    Parameters
    ----------
    panel : (int, int)
        Native panel (width, height) in pixels.
    frame : (int, int)
        Input frame (width, height) in pixels.
    keep_aspect : bool
        Keep the frame's aspect ratio (``projector.keep_aspect``).

    Returns
    -------
    (float, float, float, float)
        ``(x0, y0, w, h)`` in panel pixels: left and top edge, width and height of the frame's
        image (whole numbers).

    Examples
    --------
    >>> frame_area((800, 600), (256, 256), True)
    (100.0, 0.0, 600.0, 600.0)
    >>> frame_area((800, 600), (256, 256), False)
    (0.0, 0.0, 800.0, 600.0)
    """
    pw, ph = int(panel[0]), int(panel[1])
    fw, fh = int(frame[0]), int(frame[1])
    if min(pw, ph, fw, fh) <= 0:
        raise ValueError(f"frame_area: sizes must be positive pixels, got panel={panel}, frame={frame}")
    if not keep_aspect:
        return 0.0, 0.0, float(pw), float(ph)
    scale = min(pw / fw, ph / fh)
    w = max(pw - 2 * round((pw - fw * scale) / 2), 2 - pw % 2)
    h = max(ph - 2 * round((ph - fh * scale) / 2), 2 - ph % 2)
    return (pw - w) / 2, (ph - h) / 2, float(w), float(h)


def scale_to_panel(frame: np.ndarray, panel: tuple[int, int], keep_aspect: bool) -> np.ndarray:
    """The projector's scaler: an input frame resampled onto the native panel.

    The frame is resized into :func:`frame_area` (area averaging when shrinking, bilinear when
    enlarging) and the rest of the panel set to input 0 (the response then gives it the black
    level). A frame already at the panel's size is returned unchanged.

    Parameters
    ----------
    frame : numpy.ndarray
        float (H, W, 3) encoded input in [0, 1].
    panel : (int, int)
        Native panel (width, height) in pixels.
    keep_aspect : bool
        Keep the frame's aspect ratio (``projector.keep_aspect``).

    Returns
    -------
    numpy.ndarray
        float32 (panel height, panel width, 3).
    """
    x = np.asarray(frame, np.float32)
    pw, ph = int(panel[0]), int(panel[1])
    if x.shape[:2] == (ph, pw):
        return x
    x0, y0, w, h = (int(v) for v in frame_area((pw, ph), (x.shape[1], x.shape[0]), keep_aspect))
    shrink = x.shape[0] > h or x.shape[1] > w
    scaled = cv2.resize(x, (w, h), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)
    if (w, h) == (pw, ph):
        return scaled
    out = np.zeros((ph, pw, 3), np.float32)
    out[y0:y0 + h, x0:x0 + w] = scaled
    return out


@dataclass(frozen=True)
class ScalerOptions:
    """The key of the projector's scaler."""

    keep_aspect: bool = boolean(True)
    """True: the scaler resamples an input frame to cover the panel keeping the frame's aspect
    ratio, centred, the rest of the panel at the black level (a 256x256 frame on an 800x600 panel
    fills the central 600x600); False: stretched to fill the whole panel. A frame of the panel's
    aspect fills the panel either way."""


def _scale(frame: np.ndarray, cfg, lens) -> np.ndarray:
    return scale_to_panel(frame, cfg.resolution, cfg.keep_aspect)


SCALER = Stage("scaler", ScalerOptions, "the input frame resampled onto the native panel, on encoded "
               "values (scale_to_panel)", _scale)
"""The projector's scaler stage."""
