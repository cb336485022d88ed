"""GPU benchmark in one command: CompenNet's paper profile trained on CUDA with mixed precision, a
suite render with the ``cuda_ad_rgb`` Mitsuba variant, and the light-transport operator applied on
CUDA against the CPU.

    python benchmarks/gpu.py                      # the paper profile and 2 suite setups on CUDA
    python benchmarks/gpu.py --device cpu --size 32 --pairs 8 --iters 2 --batch 4 --frames 2

1. **Training**: CompenNet (with the surface branch) on ``--pairs`` synthetic pairs of
   ``--size``² (captures = 0.15 + 0.7 · frame · surface, 8-bit; the speed does not depend on the
   content), ``--iters`` iterations at ``--batch``, ℓ1+SSIM, Adam, mixed precision (bf16, or fp16
   on GPUs without bf16; ``--no-amp`` for float32) — the paper
   profile by default (256², 500 pairs, 1000 iterations, batch 64) — through procam's training
   loop; then prediction of the pairs.
2. **Render**: the first ``--setups`` setups of ``--suite`` rendered with ``--frames`` training
   frames and one test frame at ``--size``² into a temporary dataset root, at the ``transport``
   level (the operator is calibrated with Mitsuba, then every capture is T · frame on CUDA). Needs
   mitsuba and drjit (``benchmarks/gpu_wheels.sh`` downloads them as wheels); without them, or
   with ``--skip-render``, this part is skipped with a message and the rest still runs.
3. **Transport operator**: the calibrated operator of the first setup applied to ``--frames``
   frames with :meth:`TransportOperator.project_image` on ``--device`` and on the CPU.

Prints a table and writes ``gpu.json`` into ``--out`` (default ``benchmarks/results/gpu``).
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # run from a bare checkout, procam not installed

from compensation.data import PairSet, SetupData  # noqa: E402
from compensation.methods.compennet import CompenNetMethod, CompenNetOptions  # noqa: E402
from compensation.training.config import TrainConfig  # noqa: E402


def synthetic_data(pairs: int, size: int, seed: int = 0) -> SetupData:
    """``pairs`` smooth random frames, a textured surface and 8-bit captures of frame · surface."""
    g = torch.Generator().manual_seed(seed)
    coarse = torch.rand(pairs, 3, 8, 8, generator=g)
    frames = torch.nn.functional.interpolate(coarse, size=(size, size), mode="bicubic",
                                             align_corners=False).clamp(0, 1)
    surface = 0.45 + 0.55 * torch.rand(1, 3, size, size, generator=g)
    captures = (torch.round((0.15 + 0.7 * frames * surface) * 255) / 255).clamp(0, 1)
    pairs_set = PairSet(captures, frames)
    return SetupData("synthetic", Path("."), pairs_set, pairs_set, pairs_set, surface)


def sync(device: torch.device) -> None:
    """Wait for the device's queued kernels (timing)."""
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def bench_training(args: argparse.Namespace) -> dict:
    """Train CompenNet on synthetic pairs through procam's loop; seconds, samples/s, prediction."""
    device = torch.device(args.device)
    data = synthetic_data(args.pairs, args.size)
    options = CompenNetOptions(iters=args.iters, batch=args.batch, amp=args.amp)
    cfg = TrainConfig(method="compennet", options=options, n_train=None, n_test=None,
                      device=args.device, seed=0)
    if device.type == "cuda":
        torch.cuda.reset_peak_memory_stats(device)
    method = CompenNetMethod(device=args.device)
    start = time.perf_counter()
    fit = method.fit(data, cfg, progress=False)
    sync(device)
    total = time.perf_counter() - start
    start = time.perf_counter()
    pred = method.predict(data.test.captures, data.surface, batch_size=args.batch)
    sync(device)
    predict = time.perf_counter() - start
    mse = torch.mean((pred - data.test.frames) ** 2).item()
    out = {"size": args.size, "pairs": args.pairs, "iters": args.iters, "batch": fit.batch,
           "amp": bool(args.amp), "fit_seconds": total,
           "loop_seconds": fit.seconds, "samples_per_second": fit.samples_per_second,
           "final_loss": fit.final_loss, "predict_seconds": predict,
           "train_psnr_db": 10 * np.log10(1 / max(mse, 1e-12))}
    if device.type == "cuda":
        out["peak_memory_gib"] = torch.cuda.max_memory_allocated(device) / 2**30
    return out


def bench_render(args: argparse.Namespace) -> dict:
    """Render the first setups of the suite at the transport level; time the operator."""
    try:
        import drjit  # noqa: F401
        import mitsuba  # noqa: F401
    except ImportError as exc:
        return {"skipped": f"mitsuba/drjit not importable ({exc}); carry the wheels of "
                           "benchmarks/gpu_wheels.sh and pip install --no-index them"}
    if args.device.startswith("cuda"):
        os.environ.setdefault("PROCAM_VARIANT", "cuda_ad_rgb")
    try:
        from sim.dataset import FrameSpec, write_setup
        from sim.setup import load_setups
        from sim.transport import TransportOperator
    except ImportError as exc:  # a dependency of the simulator that this environment lacks
        return {"skipped": f"the simulator cannot be imported ({exc}); carry its wheels too"}
    setups = load_setups(args.suite)[:args.setups]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        spec = FrameSpec(args.frames, 1, (args.size, args.size))
        for setup in setups:
            start = time.perf_counter()
            folder = write_setup(Path(tmp), setup, spec, fidelity="transport", progress=False)
            seconds = time.perf_counter() - start
            meta = json.loads((folder / "meta.json").read_text())
            rows.append({"setup": setup.name, "seconds": seconds, "variant": meta.get("variant"),
                         "captures": meta.get("captures_this_run"), "timings_s": meta.get("timings_s")})
        operator = TransportOperator.load(next(Path(tmp).rglob("transport_*.npz")))
        wp, hp = operator.projector_size
        frames = np.random.default_rng(0).random((args.frames, hp, wp, 3), np.float32)
        project = {}
        for device in dict.fromkeys([args.device, "cpu"]):
            operator.project_image(frames[0], device)  # build the device's matrix once
            sync(torch.device(device))
            start = time.perf_counter()
            for f in frames:
                operator.project_image(f, device)
            sync(torch.device(device))
            project[device] = (time.perf_counter() - start) / len(frames)
    return {"suite": args.suite, "setups": rows, "operator_nnz": operator.nnz,
            "projector_size": [wp, hp],
            "project_seconds_per_frame": project}


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--device", default="cuda", help="torch device (cuda, cuda:1, cpu)")
    ap.add_argument("--size", type=int, default=256, help="image side in pixels (paper 256)")
    ap.add_argument("--pairs", type=int, default=500, help="training pairs (paper 500)")
    ap.add_argument("--iters", type=int, default=1000, help="iterations (paper 1000)")
    ap.add_argument("--batch", type=int, default=64, help="batch (paper 64)")
    ap.add_argument("--no-amp", dest="amp", action="store_false", help="train in fp32")
    ap.add_argument("--suite", default=str(ROOT / "scenes" / "suite.toml"),
                    help="setup or suite file (default: the checkout's scenes/suite.toml)")
    ap.add_argument("--setups", type=int, default=2, help="setups of the suite to render")
    ap.add_argument("--frames", type=int, default=20, help="training frames rendered per setup")
    ap.add_argument("--skip-render", action="store_true")
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "gpu"))
    args = ap.parse_args(argv)
    if args.device.startswith("cuda") and not torch.cuda.is_available():
        ap.error(f"--device {args.device}: this torch ({torch.__version__}) sees no CUDA device; "
                 "use --device cpu for a dry run")
    name = torch.cuda.get_device_name(args.device) if args.device.startswith("cuda") else platform.processor()
    result = {"device": args.device, "device_name": name, "torch": torch.__version__,
              "python": platform.python_version()}
    result["training"] = training = bench_training(args)
    print(f"{name}, torch {torch.__version__}\ntraining CompenNet {args.size}², {args.pairs} pairs, "
          f"{args.iters} iterations, batch {training['batch']}, AMP {training['amp']}: "
          f"{training['fit_seconds']:.1f} s ({training['samples_per_second']:.0f} samples/s), "
          f"prediction of {args.pairs} pairs {training['predict_seconds']:.2f} s", flush=True)
    result["render"] = render = {"skipped": "--skip-render"} if args.skip_render else bench_render(args)
    if "skipped" in render:
        print(f"render: skipped ({render['skipped']})")
    else:
        for row in render["setups"]:
            print(f"render {row['setup']} ({row['variant']}, transport): {row['captures']} captures "
                  f"in {row['seconds']:.1f} s including calibration")
        print("transport operator ({}x{} projector, nnz {}): ".format(
            *render["projector_size"], render["operator_nnz"]) + ", ".join(
            f"{d} {1000 * s:.2f} ms/frame" for d, s in render["project_seconds_per_frame"].items()))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "gpu.json").write_text(json.dumps(result, indent=2) + "\n")
    return result


if __name__ == "__main__":
    main()
