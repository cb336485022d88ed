"""Training benchmark: CompenNet samples/second of the naive loop against procam's, each speed-up
as a step of its own, measured side by side in one run: each step runs in a process of its own
and the steps take turns, one training step each per round, each reporting its median
(``benchmarks/interleave.py``).

Steps (each adds to the one above):

* ``naive``: the surface branch run per sample (s̃ repeated over the batch), default memory layout,
  pytorch-msssim's SSIM in the loss;
* ``surface once``: s̃ with batch 1, encoded once per batch and broadcast (its gradient summed over
  the batch by :func:`~compensation.methods.compennet.sum_over_batch`);
* ``channels_last``: network and images in the channels-last memory layout;
* ``ssim``: procam's SSIM (per-channel 1-D Gaussian passes in the channels-last layout);
* ``inplace relu``: in-place ReLUs;
* ``conv backward``: the convolutions' backward replacements that measured faster on this CPU
  (:func:`~compensation.training.conv_grad.faster_backward`: the transposed convolutions' backward
  as the strided convolutions they transpose; on AVX2 CPUs also the wide
  convolutions' weight gradients in the default layout; the first line says which);
* ``retained heap``: freed memory kept in the heap for the next step (:mod:`sim.heap`) — procam's
  CPU training step (:func:`~compensation.methods.compennet.fit_network`);
* ``compile`` (``--compile``): ``torch.compile`` of the network on top.

With ``--nchw-ab``, procam's step (``retained heap``) with the NCHW weight gradients forced on and
off, taking turns, per size: the A/B behind :data:`~compensation.training.conv_grad.NCHW_WEIGHT_GRADIENT_CPUS`.
With ``--amp-ab``, procam's step in float32 against the same step with its forward pass under
bf16 autocast (``procam train --amp``), taking turns, per size, and the loss of each after the same
steps from the same start.
With ``--concurrent``, procam's step as one process of all the threads against one process of one
thread per CPU, all stepping at once: what a bench or study gains by running its jobs side by
side (``--processes``) rather than one after the other.
With ``--bf16-shapes``, instead of all that: procam's bf16 step at each size and batch given, the
shapes taking turns, in 64²-window samples per second (the rate a budget of window samples, the
`faithful` profile's, is trained at).

Then, with ``--data``, the `quick` profile's training time and test PSNR/SSIM on the default setup.

With ``--runs K`` the whole comparison runs K times in fresh processes, and a last row per size
gives each step's median over the runs: the naive loop's speed depends on how the kernel serves
its page faults, which varies from process to process (±15 % between runs at 128²).

    .venv/bin/python benchmarks/train.py [--sizes 128,256] [--batches 16,8] [--rounds 7] [--runs K]
                                         [--threads N] [--pause S] [--compile] [--nchw-ab]
                                         [--amp-ab] [--concurrent] [--bf16-shapes]
                                         [--data out/data]
"""
from __future__ import annotations

import argparse
import copy
import os
import statistics
from contextlib import ExitStack
from pathlib import Path

import pytorch_msssim
import torch
import torch.nn.functional as F

from compensation.scores.losses import l1, l1_ssim
from compensation.scores.metrics import gaussian_window
from compensation.methods.compennet import CompenNet, native_bf16
from compensation.training.conv_grad import faster_backward, nchw_weight_gradients_pay
from interleave import interleaved
from sim.cores import usable_cores

STEPS = ("naive", "surface once", "channels_last", "ssim", "inplace relu", "conv backward",
         "retained heap", "compile")
"""The measured steps, in order; each adds one speed-up to the one before."""


def previous_l1_ssim(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """The loss before procam's SSIM: ℓ1 + 1 − pytorch-msssim's SSIM of the edge-padded images."""
    padded = [F.pad(t, (5,) * 4, mode="replicate") for t in (pred, target)]
    win = gaussian_window().repeat(pred.shape[1], 1, 1, 1)
    return l1(pred, target) + 1 - pytorch_msssim.ssim(*padded, data_range=1.0, win=win)


def make_step(name: str, base: CompenNet, x: torch.Tensor, y: torch.Tensor, s: torch.Tensor,
              nchw: bool | None = None, amp: bool = False):
    """One training step (forward, ℓ1+SSIM, backward, Adam) of the step ``name`` of :data:`STEPS`;
    ``nchw`` forces the NCHW weight gradients on or off (None: this CPU's rule); ``amp`` runs the
    forward pass under bf16 autocast, as :func:`~compensation.methods.compennet.fit_network`
    does with ``amp``."""
    level = STEPS.index(name)
    model = copy.deepcopy(base)
    for m in model.modules():
        if isinstance(m, torch.nn.ReLU):
            m.inplace = level >= STEPS.index("inplace relu")
    if level == 0:
        s = s.expand(x.shape[0], -1, -1, -1).contiguous()  # per sample
    if level >= STEPS.index("channels_last"):
        layout = torch.channels_last
        model = model.to(memory_format=layout)
        x, y, s = (t.contiguous(memory_format=layout) for t in (x, y, s))
    loss_fn = l1_ssim if level >= STEPS.index("ssim") else previous_l1_ssim
    patches = ExitStack()
    if level >= STEPS.index("conv backward"):
        patches.enter_context(faster_backward(model, nchw))
    forward = torch.compile(model) if name == "compile" else model
    opt = torch.optim.Adam(model.parameters(), lr=1e-3, weight_decay=1e-4)

    def step() -> float:
        opt.zero_grad(set_to_none=True)
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=amp):
            pred = forward(x, s)
        loss = loss_fn(pred.float(), y)
        loss.backward()
        opt.step()
        return loss.item()
    step.model, step.patches = model, patches  # the layers stay changed while the step lives
    return step


def build_step(name: str, size: int, batch: int, threads: int | None, nchw: bool | None = None,
               amp: bool = False):
    """Step ``name`` on seeded random images of ``size``² at ``batch`` (in its worker process)."""
    if threads:
        torch.set_num_threads(threads)
    torch.manual_seed(0)
    base = CompenNet(surface=True)
    x, y, s = torch.rand(batch, 3, size, size), torch.rand(batch, 3, size, size), torch.rand(1, 3, size, size)
    return make_step(name, base, x, y, s, nchw, amp)


def compare(size: int, batch: int, rounds: int, steps: tuple[str, ...], threads: int | None,
            pause: float) -> dict[str, float]:
    """Median samples/second of each step, the steps taking turns for ``rounds`` rounds."""
    kept = STEPS.index("retained heap")
    seconds = interleaved({name: (build_step, (name, size, batch, threads), STEPS.index(name) >= kept)
                           for name in steps}, rounds, pause)
    return {name: batch / statistics.median(t) for name, t in seconds.items()}


def ab(size: int, batch: int, rounds: int, threads: int | None, pause: float,
       arms: dict[str, tuple[bool | None, bool]]) -> dict[str, float]:
    """Median samples/second of procam's step in each arm, by label: its ``(nchw, amp)`` values of
    :func:`make_step`, the arms taking turns for ``rounds`` rounds."""
    seconds = interleaved({label: (build_step, ("retained heap", size, batch, threads, *arm), True)
                           for label, arm in arms.items()}, rounds, pause)
    return {name: batch / statistics.median(t) for name, t in seconds.items()}


def amp_losses(size: int, batch: int, steps: int) -> dict[str, float]:
    """The loss after ``steps`` training steps on the same seeded images from the same start, in
    float32 and under bf16 autocast (in this process)."""
    return {label: [build_step("retained heap", size, batch, None, None, on)() for _ in range(steps)][-1]
            for label, on in (("float32", False), ("bf16", True))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", default="128,256")
    ap.add_argument("--batches", default="16,8", help="batch per size")
    ap.add_argument("--rounds", type=int, default=7)
    ap.add_argument("--runs", type=int, default=1, help="repeat the comparison in fresh processes")
    ap.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's)")
    ap.add_argument("--pause", type=float, default=0.05, help="seconds of rest before each timed step")
    ap.add_argument("--compile", action="store_true", help="also time torch.compile (slow to build)")
    ap.add_argument("--nchw-ab", action="store_true", help="also time procam's step with the NCHW "
                    "weight gradients on against off, whatever this CPU's rule")
    ap.add_argument("--amp-ab", action="store_true", help="also time procam's step in float32 "
                    "against bf16 autocast (--amp)")
    ap.add_argument("--bf16-shapes", action="store_true", help="instead: procam's bf16 step (the "
                    "faithful profile's) at every size and batch given, the shapes taking turns, in "
                    "64²-window samples/s (pixels per second over 64²)")
    ap.add_argument("--concurrent", action="store_true", help="also time procam's step (bf16 where "
                    "this CPU has it natively) as one process of all the threads against one process "
                    "of one thread per CPU, all stepping at once: the throughput of jobs run side by side")
    ap.add_argument("--data", default=None, help="a dataset root with default/ rendered at the quick "
                    "profile (e.g. the demo's out/data): also time the quick profile on it")
    args = ap.parse_args()
    steps = STEPS if args.compile else STEPS[:-1]
    sizes = [int(v) for v in args.sizes.split(",")]
    batches = [int(v) for v in args.batches.split(",")]
    threads = args.threads or torch.get_num_threads()
    shapes = list(zip(sizes, batches * len(sizes) if len(batches) == 1 else batches))
    if args.bf16_shapes:
        print(f"torch {torch.__version__}, {threads} threads, load average before {os.getloadavg()[0]:.1f}; "
              f"procam's step under bf16 autocast, median of {args.rounds} interleaved steps "
              f"(bf16 natively: {native_bf16()})")
        seconds = interleaved({f"{size}x{batch}": (build_step, ("retained heap", size, batch, args.threads,
                                                                 None, True), True)
                               for size, batch in shapes}, args.rounds, args.pause)
        for size, batch in shapes:
            step = statistics.median(seconds[f"{size}x{batch}"])
            print(f"  {size}², batch {batch}: {1000 * step:.1f} ms a step, "
                  f"{batch * (size / 64) ** 2 / step:.1f} 64²-window samples/s", flush=True)
        print(f"load average after {os.getloadavg()[0]:.1f}")
        return
    print(f"torch {torch.__version__}, {threads} threads, {os.cpu_count()} CPUs, "
          f"load average before {os.getloadavg()[0]:.1f}; samples/s (× naive), median of "
          f"{args.rounds} interleaved steps; conv backward: transposed as strided, "
          f"NCHW weight gradients {'on' if nchw_weight_gradients_pay() else 'off'} "
          f"({torch.backends.cpu.get_cpu_capability()})")
    print(f"{'size':>5}{'batch':>6}" + "".join(f"{name:>20}" for name in steps))

    def row(label: str, rates: dict[str, float], ratios: dict[str, float]) -> None:
        cells = [f"{rates[n]:.2f} ({ratios[n]:.2f}×)" for n in steps]
        print(f"{label:>11}" + "".join(f"{c:>20}" for c in cells), flush=True)

    for size, batch in shapes:
        runs = []
        for _ in range(args.runs):
            rates = compare(size, batch, args.rounds, steps, args.threads, args.pause)
            runs.append((rates, {n: rates[n] / rates["naive"] for n in steps}))
            row(f"{size:>5}{batch:>6}", *runs[-1])
        if args.runs > 1:
            row("median", *({n: statistics.median(r[i][n] for r in runs) for n in steps}
                             for i in (0, 1)))
    if args.nchw_ab:
        print("procam's step, NCHW weight gradients on against off (samples/s, median of "
              f"{args.rounds} interleaved steps):")
        for size, batch in shapes:
            rates = ab(size, batch, args.rounds, args.threads, args.pause,
                       {"NCHW on": (True, False), "NCHW off": (False, False)})
            print(f"  {size}², batch {batch}: on {rates['NCHW on']:.2f}, off {rates['NCHW off']:.2f}, "
                  f"on/off {rates['NCHW on'] / rates['NCHW off']:.3f}×", flush=True)
    if args.amp_ab:
        print(f"procam's step, float32 against bf16 autocast (samples/s, median of {args.rounds} "
              f"interleaved steps; loss after {args.rounds} steps from the same start; bf16 natively: "
              f"{native_bf16()}):")
        for size, batch in shapes:
            rates = ab(size, batch, args.rounds, args.threads, args.pause,
                       {"float32": (None, False), "bf16": (None, True)})
            losses = amp_losses(size, batch, args.rounds)
            print(f"  {size}², batch {batch}: float32 {rates['float32']:.2f}, bf16 {rates['bf16']:.2f}, "
                  f"bf16/float32 {rates['bf16'] / rates['float32']:.2f}×; loss {losses['float32']:.6f} "
                  f"against {losses['bf16']:.6f}", flush=True)
    if args.concurrent:
        amp, cpus = native_bf16(), usable_cores()
        print(f"procam's step in {'bf16' if amp else 'float32'}, one process of {threads} threads against "
              f"{cpus} processes of one thread stepping at once (samples/s of all of them, median of "
              f"{args.rounds} rounds of their mean step time):")
        for size, batch in shapes:
            seconds = interleaved({"one": (build_step, ("retained heap", size, batch, threads, None, amp), True),
                                   "each": (build_step, ("retained heap", size, batch, 1, None, amp), True, cpus)},
                                  args.rounds, args.pause)
            one = batch / statistics.median(seconds["one"])
            each = cpus * batch / statistics.median(seconds["each"])
            print(f"  {size}², batch {batch}: one process {one:.2f}, {cpus} processes {each:.2f}, "
                  f"{each / one:.2f}×", flush=True)
    print(f"load average after {os.getloadavg()[0]:.1f}")
    if args.data:
        import tempfile

        from compensation.methods import make_config
        from compensation.experiments.runs import train_run

        with tempfile.TemporaryDirectory() as tmp:
            m = train_run(Path(args.data) / "default", make_config("quick"), Path(tmp) / "run")
        print(f"\nquick profile on default: {m['train_seconds']:.0f} s training, test PSNR "
              f"{m['psnr']:.2f} dB, SSIM {m['ssim']:.4f} (uncompensated {m['uncompensated']['psnr']:.2f} dB, "
              f"{m['uncompensated']['ssim']:.4f})")


if __name__ == "__main__":
    main()
