"""compensation.data: loading a setup's pairs and naming exactly what is wrong with a dataset."""
from __future__ import annotations

import json
import os
import re
import shutil

import numpy as np
import pytest
import torch

from compensation.data import load_setup_data
from sim.layout import image_name
from sim.errors import DatasetError
from sim.io import read_png, write_png
from synthetic import albedo_pattern, capture, make_dataset


@pytest.fixture
def fresh(tmp_path):
    """A setup of its own, for tests that damage it."""
    return make_dataset(tmp_path, n_train=6, n_test=2)


def test_shapes_values_and_alignment(setup_dir):
    data = load_setup_data(setup_dir)
    assert data.name == "synth" and data.size == (32, 32)
    assert data.train.captures.shape == data.train.frames.shape == (16, 3, 32, 32)
    assert data.test.captures.shape == (4, 3, 32, 32) and len(data.test) == 4
    assert data.ref.frames.shape == (125, 3, 32, 32)
    assert data.surface.shape == (1, 3, 32, 32)
    for t in (data.train.captures, data.train.frames, data.surface):
        assert t.dtype == torch.float32 and 0 <= t.min() and t.max() <= 1
    # Pair i really is frame i and its capture: the known degradation maps one onto the other.
    frames = (data.train.frames.permute(0, 2, 3, 1).numpy() * 255).round().astype(np.uint8)
    expected = capture(frames, albedo_pattern(32)).astype(np.float32) / 255
    assert np.array_equal(data.train.captures.permute(0, 2, 3, 1).numpy(), expected)
    # The plain colours: 0001 black, 0125 white; the surface is the capture of the gray frame.
    assert data.ref.frames[0].max() == 0 and data.ref.frames[-1].min() == 1
    gray = capture(np.full((1, 32, 32, 3), 128, np.uint8), albedo_pattern(32))[0]
    assert np.array_equal(data.surface[0].permute(1, 2, 0).numpy(), gray.astype(np.float32) / 255)


def test_first_n_pairs(setup_dir):
    full = load_setup_data(setup_dir)
    part = load_setup_data(setup_dir, n_train=5, n_test=3)
    assert len(part.train) == 5 and len(part.test) == 3
    assert torch.equal(part.train.frames, full.train.frames[:5])
    assert torch.equal(part.test.captures, full.test.captures[:3])


def test_missing_setup_dir(tmp_path):
    with pytest.raises(DatasetError, match=re.escape(f"{tmp_path / 'nowhere'}: setup folder not found")):
        load_setup_data(tmp_path / "nowhere")


def test_unfinished_setup(tmp_path):
    setup = make_dataset(tmp_path, n_train=2, n_test=1, finished=False)
    with pytest.raises(DatasetError, match=re.escape(f"{setup}: setup is not finished (no meta.json)")):
        load_setup_data(setup)


def test_missing_captures_are_named(fresh):
    (fresh / "cam/warp/train/img_0002.png").unlink()
    (fresh / "cam/warp/train/img_0005.png").unlink()
    message = (f"{fresh / 'cam/warp/train'}: 4 captures but {fresh.parent / 'train'} has 6 frames; "
               "missing img_0002.png, img_0005.png")
    with pytest.raises(DatasetError, match=re.escape(message)):
        load_setup_data(fresh)


def test_missing_frame_is_named(fresh):
    (fresh.parent / "test/img_0002.png").unlink()
    with pytest.raises(DatasetError, match=re.escape(f"{fresh.parent / 'test'}: 1 frames but "
                                                     f"{fresh / 'meta.json'} lists 2; missing img_0002.png")):
        load_setup_data(fresh)


def test_meta_counts_limit_pairs_when_the_root_has_more_frames(fresh):
    """A root extended with more frames later (for a larger setup) leaves this setup usable."""
    write_png(fresh.parent / "train/img_0007.png", read_png(fresh.parent / "train/img_0001.png"))
    assert len(load_setup_data(fresh).train) == 6
    meta = json.loads((fresh / "meta.json").read_text())
    meta["counts"]["train"] = 7
    (fresh / "meta.json").write_text(json.dumps(meta))
    with pytest.raises(DatasetError, match=re.escape(
            f"{fresh / 'cam/warp/train'}: 6 captures but {fresh.parent / 'train'} has 7 frames; "
            "missing img_0007.png")):
        load_setup_data(fresh)


def test_missing_surface(fresh):
    (fresh / "cam/warp/ref/img_0126.png").unlink()
    with pytest.raises(DatasetError, match=re.escape(f"{fresh / 'cam/warp/ref'}: 125 PNG images; the "
                                                     "surface image s̃ (capture of the gray frame) is the 126th")):
        load_setup_data(fresh)


def test_official_benchmark_layout(tmp_path, setup_dir):
    """Nested setups with only cam/warp, the surface as img_gray.png, no meta.json: the official
    benchmark loads as procam's own layout does, the frames from the root three levels up."""
    nested = make_dataset(tmp_path, name="light2/pos1/curves", official=True)
    assert not (nested / "meta.json").exists() and (tmp_path / "ref/img_gray.png").exists()
    official, own = load_setup_data(nested), load_setup_data(setup_dir)
    assert official.name == "light2/pos1/curves" and official.setup_dir == nested
    for split in ("train", "test", "ref"):
        for kind in ("captures", "frames"):
            assert torch.equal(getattr(getattr(official, split), kind), getattr(getattr(own, split), kind))
    assert torch.equal(official.surface, own.surface)
    assert len(load_setup_data(nested, n_train=5).train) == 5


def test_frames_root_must_exist(tmp_path):
    setup = make_dataset(tmp_path / "root", name="a/b", official=True)
    shutil.rmtree(tmp_path / "root/test")
    with pytest.raises(DatasetError, match=re.escape(f"{setup}: no folder above it holds the projector "
                                                     "frames (train/ and test/")):
        load_setup_data(setup)
    (setup / "cam/warp").rename(setup / "cam/other")
    with pytest.raises(DatasetError, match=re.escape(f"{setup}: not a setup (no cam/warp captures")):
        load_setup_data(setup)


def test_own_layout_is_what_the_official_loader_reads(setup_dir):
    """The official loader reads a folder's sorted file list: procam's captures and frames align by
    position, and the 126th capture of cam/warp/ref is the surface image."""
    root = setup_dir.parent
    ref = sorted(os.listdir(setup_dir / "cam/warp/ref"))
    assert len(ref) == 126 and ref[125] == "img_0126.png" == image_name(126)
    for split in ("train", "test"):
        assert sorted(os.listdir(setup_dir / "cam/warp" / split)) == sorted(os.listdir(root / split))


def test_missing_plain_colour_capture(fresh):
    (fresh / "cam/warp/ref/img_0042.png").unlink()
    with pytest.raises(DatasetError, match=re.escape(f"{fresh / 'cam/warp/ref'}: 124 of the 125 plain "
                                                     "colour images; missing img_0042.png")):
        load_setup_data(fresh)


def test_size_mismatch_names_the_file(fresh):
    bad = fresh / "cam/warp/test/img_0002.png"
    write_png(bad, np.zeros((28, 32, 3), np.uint8))
    with pytest.raises(DatasetError, match=re.escape(f"{bad}: 32x28 pixels but "
                                                     f"{fresh / 'cam/warp/ref/img_0126.png'} is 32x32")):
        load_setup_data(fresh)


def test_size_not_divisible_by_4(tmp_path):
    setup = make_dataset(tmp_path, size=30, n_train=2, n_test=1)
    with pytest.raises(DatasetError, match="30x30 pixels; CompenNet needs width and height divisible by 4"):
        load_setup_data(setup)


@pytest.mark.parametrize("split, n", [("train", 7), ("test", 3)])
def test_more_pairs_than_available(fresh, split, n):
    with pytest.raises(DatasetError, match=re.escape(f"{fresh / 'cam/warp' / split}: n_{split}={n} asked "
                                                     f"for but the setup has only {n - 1} {split} pairs")):
        load_setup_data(fresh, **{f"n_{split}": n})


def test_without_counts_every_frame_of_the_root_is_expected(fresh):
    (fresh / "meta.json").write_text("{}")
    assert len(load_setup_data(fresh).train) == 6
    (fresh.parent / "train/img_0003.png").unlink()
    with pytest.raises(DatasetError, match=re.escape(f"{fresh.parent / 'train'}: 5 frames but they are "
                                                     "numbered up to 6; missing img_0003.png")):
        load_setup_data(fresh)


def test_unreadable_meta(fresh):
    (fresh / "meta.json").write_text("[1, 2]")
    with pytest.raises(DatasetError, match=re.escape(f"{fresh / 'meta.json'}: expected a JSON object")):
        load_setup_data(fresh)


@pytest.mark.slow
def test_a_root_without_ref_frames_loads_and_tps_says_what_it_needs(tmp_path):
    """ROOT/ref (the plain colours' projector frames) is optional, as for the official code:
    CompenNet trains without it, TPS and Nayar refuse naming what they need."""
    from compensation.experiments.runs import train_run
    from compensation.methods import make_config
    from sim.errors import ProcamError

    setup = make_dataset(tmp_path, name="light2/pos1/curves", official=True, n_train=8, n_test=2)
    for f in (tmp_path / "ref").glob("img_0*.png"):
        f.unlink()
    data = load_setup_data(setup)
    assert data.ref is None and len(data.train) == 8 and data.surface.shape[0] == 1
    metrics = train_run(setup, make_config("quick", "compennet", iters=2, batch=2, device="cpu", n_train=8,
                                           n_test=2),
                        tmp_path / "run", progress=False)
    assert np.isfinite(metrics["psnr"])
    for method in ("tps", "nayar"):
        with pytest.raises(ProcamError, match=re.escape(f"{setup}: {method} fits the 125 plain colours, "
                                                        "but the dataset root holds no ref/img_0001.png")):
            train_run(setup, make_config("quick", method, device="cpu", n_train=8, n_test=2), tmp_path / method,
                      progress=False)
    write_png(tmp_path / "ref" / "img_0001.png", np.zeros((4, 4, 3), np.uint8))  # some but not all: an error
    with pytest.raises(DatasetError, match="1 of the 125 plain colour images; missing"):
        load_setup_data(setup)
