"""Shared fixtures: Mitsuba variants, the synthetic dataset, the tiny rendered dataset, JIT cache
hygiene. The helpers the test modules share are in ``helpers.py``."""
from __future__ import annotations

import os

import pytest

from sim.variant import FALLBACK, choose_variant

VARIANTS = sorted({choose_variant(), FALLBACK})

def pytest_configure(config):
    """Under pytest-xdist (``make test`` runs one worker per core) each worker computes with one
    torch thread: the CompenNet-heavy non-square module's fixture took 194 s beside the other worker
    with two threads, 154 s with one (88 s alone with two)."""
    if os.environ.get("PYTEST_XDIST_WORKER"):
        import torch

        torch.set_num_threads(1)


@pytest.fixture(params=VARIANTS)
def variant(request):
    """Each test using it runs once per available variant (the vectorised one and scalar)."""
    return request.param


@pytest.fixture(scope="session")
def setup_dir(tmp_path_factory):
    """A finished synthetic dataset (:func:`synthetic.make_dataset` defaults), shared by the session:
    read it, never write into it."""
    from synthetic import make_dataset

    return make_dataset(tmp_path_factory.mktemp("data"))


@pytest.fixture(scope="module")
def data(setup_dir):
    """The synthetic dataset loaded with :func:`compensation.data.load_setup_data`."""
    from compensation.data import load_setup_data

    return load_setup_data(setup_dir)


@pytest.fixture(scope="session")
def tiny_render(tmp_path_factory):
    """`procam render` of :func:`helpers.tiny_setup_file` with :data:`helpers.TINY_RENDER`, shared by the
    session: a folder holding the setup file ``tiny.toml`` and the dataset root ``data/``. Read it or
    copy it, never write into it."""
    from compensation.cli import main
    from helpers import TINY_RENDER, tiny_setup_file

    folder = tmp_path_factory.mktemp("tiny_render")
    assert main(["render", str(tiny_setup_file(folder)), "--out", str(folder / "data"), *TINY_RENDER]) == 0
    return folder


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

    colour-science calls ``np.set_printoptions(legacy="1.13")`` when it is imported (by the first
    capture's response curve, :mod:`sim.camera.response`, or a colour temperature or ΔE), which
    changes how arrays and numpy scalars print; whether it has been imported before a doctest runs
    depends on the collection order. The examples are written in numpy's own
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
