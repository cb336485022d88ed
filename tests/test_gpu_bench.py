"""benchmarks/gpu.py in its CPU dry-run form, so that the GPU script cannot rot: every part runs
(training through procam's loop, a transport render of a shipped setup, the operator timing), the
rate is the loop's, and its JSON holds what the report prints."""
from __future__ import annotations

import importlib.util
import json
import math
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "gpu.py"
SCENES = SCRIPT.parents[1] / "scenes"

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def load_script():
    spec = importlib.util.spec_from_file_location("gpu_bench", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.slow
def test_gpu_benchmark_dry_run_on_cpu(tmp_path, capsys):
    result = load_script().main(["--device", "cpu", "--size", "32", "--pairs", "8", "--iters", "2",
                                 "--batch", "4", "--suite", str(SCENES / "ideal.toml"), "--setups", "1",
                                 "--frames", "2", "--out", str(tmp_path)])
    assert json.loads((tmp_path / "gpu.json").read_text()) == result
    training = result["training"]
    assert (training["size"], training["pairs"], training["iters"], training["batch"], training["amp"]) == \
           (32, 8, 2, 4, True)  # bf16 autocast, on the CPU too
    # the rate is the loop's: iterations × batch over the loop's seconds, within the whole fit's
    assert math.isclose(training["samples_per_second"], 2 * 4 / training["loop_seconds"], rel_tol=1e-9)
    assert 0 < training["loop_seconds"] <= training["fit_seconds"] and training["predict_seconds"] > 0
    assert math.isfinite(training["final_loss"]) and math.isfinite(training["train_psnr_db"])
    render = result["render"]
    assert [row["setup"] for row in render["setups"]] == ["ideal"]
    assert render["setups"][0]["captures"] == 2 + 1 + 126  # train, test, 125 plain colours + gray
    assert render["operator_nnz"] > 32 * 32 and set(render["project_seconds_per_frame"]) == {"cpu"}
    out = capsys.readouterr().out
    assert (f"training CompenNet 32², 8 pairs, 2 iterations, batch 4, AMP True: "
            f"{training['fit_seconds']:.1f} s ({training['samples_per_second']:.0f} samples/s)") in out
    assert f"render ideal ({render['setups'][0]['variant']}, transport): 129 captures" in out
    width, height = render["projector_size"]
    assert (f"transport operator ({width}x{height} projector, nnz {render['operator_nnz']}): "
            f"cpu {1000 * render['project_seconds_per_frame']['cpu']:.2f} ms/frame") in out


def test_gpu_benchmark_refuses_a_missing_cuda_device(capsys):
    import torch

    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA")
    with pytest.raises(SystemExit):
        load_script().main(["--device", "cuda"])
    assert "sees no CUDA device; use --device cpu" in capsys.readouterr().err
