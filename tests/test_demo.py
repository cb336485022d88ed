"""``procam demo`` end to end on a tiny size: the table's rows, the figure and the JSON on disk."""
import json

import imageio.v3 as iio

from compensation.demo import METHODS, N_FIGURE, run_demo


def test_demo_tiny(tmp_path, capsys):
    results = run_demo(tmp_path, progress=False, size=32, n_train=16, n_test=N_FIGURE, iters=20, batch=4)
    out = capsys.readouterr().out
    for name in METHODS:
        assert f"{name}: surrogate" in out and f"{name}: closed loop" in out
        assert 0 < results[name]["closed_loop"]["psnr"] < 60
        assert 0 <= results[name]["closed_loop"]["reachable_fraction"] <= 1
    assert "oracle: feedback" in out and "physically reachable" in out
    # the oracle corrects by the measured error: it must beat y projected as is
    assert results["oracle"][-1]["psnr"] > results["uncompensated"]["psnr"]
    assert json.loads((tmp_path / "demo.json").read_text()).keys() == results.keys()
    grid = iio.imread(tmp_path / "demo.png")
    assert grid.ndim == 3 and grid.shape[2] == 3 and grid.shape[1] > grid.shape[0]  # 5 columns × 4 rows
    # resumable: a second run reuses the dataset and the runs and gives the same numbers
    again = run_demo(tmp_path, progress=False, size=32, n_train=16, n_test=N_FIGURE, iters=20, batch=4)
    assert again[METHODS[0]]["surrogate"] == results[METHODS[0]]["surrogate"]
