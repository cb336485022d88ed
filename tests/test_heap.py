"""sim.heap: freed memory kept in the heap inside retained_heap (no page faults on reuse), given back
on exit, nesting, and unchanged values. The memory measurements run in a fresh child process."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest
import torch

from sim import heap

pytestmark = pytest.mark.skipif(heap._glibc() is None, reason="retained_heap acts on glibc only")

BIG = 64 << 20
"""Bytes of the test's arrays: above glibc's largest mmap threshold (32 MiB), so mapped by default."""

CHILD = """
import json, os, resource, sys
import numpy as np
from sim import heap

BIG = int(sys.argv[1])

def faults_of_reallocation():
    np.ones(BIG // 8).sum()  # allocated and freed once before
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    np.ones(BIG // 8).sum()
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before

def resident():
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")

out = {"outside": faults_of_reallocation()}
with heap.retained_heap() as out["applies"]:
    out["inside"] = faults_of_reallocation()
    with heap.retained_heap():
        pass
    out["after_inner_exit"] = faults_of_reallocation()
    base = resident()
    np.ones(4 * BIG // 8).sum()  # allocated, touched and freed
    out["kept"] = resident() - base
out["released"] = base + out["kept"] - resident()
print(json.dumps(out))
"""


@pytest.fixture(scope="module")
def measured() -> dict:
    """The child's measurements: in a fresh process, whose heap no earlier test has grown (glibc
    serves a large request from a free heap chunk before it maps one)."""
    proc = subprocess.run([sys.executable, "-c", CHILD, str(BIG)], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout)


def test_reallocation_faults_only_inside(measured):
    # By default a 64 MiB array is a fresh mapping each time: at least one fault per 2 MiB page
    # even with transparent huge pages (16,384 with 4 KiB pages).
    assert measured["applies"]
    assert measured["outside"] >= BIG // (2 << 20)
    assert measured["inside"] <= 8, measured


def test_nested_blocks_keep_the_policy_until_the_outermost_ends(measured):
    assert measured["after_inner_exit"] <= 8, measured


def test_freed_memory_is_kept_inside_and_given_back_on_exit(measured):
    # 256 MiB allocated and freed inside: still resident, ready for the next iteration (the first
    # 64 MiB may reuse the free chunk of the earlier arrays), and given back on exit
    assert measured["kept"] > 2 * BIG, measured
    assert measured["released"] > 3 * BIG, measured


def test_training_steps_give_the_same_values():
    def train() -> torch.Tensor:
        torch.manual_seed(0)
        net = torch.nn.Sequential(torch.nn.Conv2d(3, 64, 3, padding=1), torch.nn.ReLU(),
                                  torch.nn.Conv2d(64, 3, 3, padding=1))
        opt = torch.optim.Adam(net.parameters())
        x = torch.rand(8, 3, 96, 96)
        for _ in range(3):
            opt.zero_grad()
            (net(x) - x).abs().mean().backward()
            opt.step()
        return torch.cat([p.detach().flatten() for p in net.parameters()])

    plain = train()
    with heap.retained_heap():
        kept = train()
    assert torch.equal(plain, kept)
