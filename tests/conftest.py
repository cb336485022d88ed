"""Shared fixtures: Mitsuba variants, tiny setups, the synthetic dataset, JIT cache hygiene."""
from __future__ import annotations

import copy

import pytest

from sim.variant import FALLBACK, choose_variant

# A small, fast setup (64² camera, 64² projector): the physics tests build variations of it.
TINY = {
    "name": "tiny",
    "surface": {"geometry": "plane", "size": [1.2, 1.0], "texture": "uniform", "albedo_scale": 0.8},
    "projector": {"resolution": [64, 64], "fov": 30.0, "position": [0.0, 0.0, 1.0],
                  "black_level": 0.0},
    "camera": {"resolution": [64, 64], "fov": 40.0, "position": [0.25, 0.0, 1.0],
               "shot_noise": 0.0, "read_noise": 0.0},
    "ambient": {"radiance": [0.0, 0.0, 0.0]},
    "render": {"fidelity": "direct", "spp": 4, "ambient_spp": 16, "seed": 0},
}


def tiny_setup(**sections):
    """A validated tiny setup; keyword arguments override keys per section, e.g.
    ``tiny_setup(camera={"position": [0, 0, 1]})``."""
    from sim.setup import parse_setup

    data = copy.deepcopy(TINY)
    for section, values in sections.items():
        if isinstance(values, dict):
            data.setdefault(section, {}).update(values)
        else:
            data[section] = values
    return parse_setup(data, source="<tiny>")



def tiny_toml(name: str = "base", side: int = 32, texture: str = "noise") -> str:
    """A tiny setup file's text (side² projector and camera, direct light at 4 spp), the base of
    the suites and studies the end-to-end tests write to disk."""
    return f"""
name = "{name}"
[surface]
texture = "{texture}"
texture_resolution = 64
[projector]
resolution = [{side}, {side}]
[camera]
resolution = [{side}, {side}]
[render]
fidelity = "direct"
spp = 4
ambient_spp = 16
"""

VARIANTS = sorted({choose_variant(), FALLBACK})


@pytest.fixture(params=VARIANTS)
def variant(request):
    """Each test using it runs once per available variant (the vectorised one and scalar)."""
    return request.param


@pytest.fixture(scope="module")
def setup_dir(tmp_path_factory):
    """A finished synthetic dataset (:func:`synthetic.make_dataset` defaults), one per module."""
    from synthetic import make_dataset

    return make_dataset(tmp_path_factory.mktemp("data"))


@pytest.fixture(scope="module")
def data(setup_dir):
    """The synthetic dataset loaded with :func:`compensation.data.load_setup_data`."""
    from compensation.data import load_setup_data

    return load_setup_data(setup_dir)


@pytest.fixture(scope="module")
def one_torch_thread():
    """One intra-op torch thread for a module, then the previous count: 32² batches gain nothing from
    more, and on a shared machine two OpenMP threads spin-wait against other processes (measured
    10× slower than one)."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(autouse=True, scope="module")
def _flush_jit():
    """Clear Dr.Jit's kernel and memory caches after each test module."""
    yield
    import drjit as dr

    dr.flush_kernel_cache()
    dr.flush_malloc_cache()


def pytest_collection_modifyitems(items):
    """Run the doctests of ``sim/`` and ``compensation/`` under numpy's default print options.

    colour-science calls ``np.set_printoptions(legacy="1.13")`` when it is imported (by
    ``sim.camera``), which changes how arrays and numpy scalars print; whether it has been imported
    before a doctest runs depends on the collection order. The examples are written in numpy's own
    format, so each doctest runs under the defaults, and the previous options are restored after it.
    """
    import numpy as np
    from _pytest.doctest import DoctestItem

    for item in items:
        if isinstance(item, DoctestItem):
            def runtest(run=item.runtest):
                with np.printoptions(legacy=False):
                    run()

            item.runtest = runtest
