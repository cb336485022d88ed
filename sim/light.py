"""How much of the light a camera sees is not the projector's direct light, measured in the
canonical view: the room light as a share of the projector's white, and the projector's light
that the surface throws back onto itself (inter-reflection) as a share of its direct light.

A study records these beside the factor that sets them, so that its axis reads in what a reader
compares across setups ("room light 10 % of projector white", "indirect light 12 % of direct").
"""
from __future__ import annotations

import numpy as np

from sim import registration, seeds, surfaces
from sim.capture import Simulator
from sim.fidelity import make_renderer, with_depth
from sim.render import Renderer

AXIS_SHARES = {"ambient.radiance": "ambient", "ambient.intensity": "ambient"}
"""Setup keys whose value sets one share of :func:`light_shares` (a study's axis on such a key
records that share, measured, per value)."""
SHARE_NAMES = {"ambient": ("room light", "% of projector white"),
               "indirect": ("indirect light", "% of direct light")}
"""Each share's label and unit as a study records it (in percent)."""


def _seen_mean(sim: Simulator, radiance: np.ndarray) -> float:
    """Mean linear radiance (all channels) over the canonical view's seen pixels (NaN if none)."""
    canonical = registration.warp(np.asarray(radiance, np.float32), sim.warp_map)
    seen = canonical[sim.warp_map.mask]
    return float(seen.mean()) if seen.size else float("nan")


def _share(part: float, whole: float) -> float | None:
    """``part / whole``, or None where the whole is not a positive number (nothing lit)."""
    return part / whole if whole > 0 else None


def light_shares(sim: Simulator) -> dict:
    """The room light and the inter-reflected light of a simulator's setup, as shares.

    Parameters
    ----------
    sim : Simulator
        The setup's simulator (its renderer, registration and exposure as the captures use them).

    Returns
    -------
    dict
        ``ambient``: the mean linear radiance of the room light alone over the canonical view's
        seen pixels, over that of the projector's white frame (projector light only, at the
        captures' rendering level; 0.1: the room adds 10 % of the projector's white).
        ``indirect``: for a surface that lights itself, the projector's white path-traced at the
        captures' depth minus its direct light (the ``direct`` level), over the direct light, in
        the same view; 0 for a surface that cannot (a plane). Each None where its denominator is
        not positive (no seen pixel lit).
    """
    w, h = sim.size
    white = np.full((h, w, 3), 255, np.uint8)
    r = sim.setup.render

    def lit(renderer: Renderer, index: int) -> float:
        seed = seeds.mitsuba_seed(r.seed, seeds.LIGHT, index)
        light = renderer.projector_radiance(renderer.emit(white), seed)
        return _seen_mean(sim, light)

    projector = lit(sim.renderer, 0)
    ambient = _share(_seen_mean(sim, sim.renderer.ambient_radiance()), projector)
    indirect = 0.0
    if surfaces.surface_for(sim.setup.surface).interreflection:
        path = (projector if sim.choice.level == "path" else
                lit(make_renderer(with_depth(sim.setup, sim.choice.max_depth), "path", sim.choice.spp), 1))
        # The direct level drops the inter-reflection, which is what it measures here (a capture
        # renderer may not: make_renderer refuses it for such a surface).
        direct = lit(Renderer(sim.setup, "direct", sim.choice.spp), 2)
        indirect = _share(path - direct, direct)
    return {"ambient": ambient, "indirect": indirect}
