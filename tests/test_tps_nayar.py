"""compensation.methods.tps and compensation.methods.nayar: the per-pixel baselines against planted models,
scipy's RBFInterpolator, and the training registry on the tiny synthetic setup."""
from __future__ import annotations

import json
import re
from dataclasses import replace

import numpy as np
import pytest
import torch
from scipy.interpolate import RBFInterpolator

from compensation.data import PairSet, SetupData
from compensation.experiments.official import official_tag
from compensation.methods import get_method, make_config, nayar, tps
from compensation.training.config import NoOptions, TrainConfig
from compensation.experiments.runs import load_run, train_run
from sim.errors import ProcamError

STATE = {"tps": tps.STATE_FILE, "tps-textured": tps.STATE_FILE, "nayar": nayar.STATE_FILE}


def grid(levels: int) -> np.ndarray:
    """The plain colours: ``levels``³ RGB values on a regular grid in [0, 1], (levels³, 3)."""
    lv = np.linspace(0.0, 1.0, levels)
    return np.stack(np.meshgrid(lv, lv, lv, indexing="ij"), axis=-1).reshape(-1, 3)


def planted_capture(p: np.ndarray, pixels: int, bend, seed: int = 0) -> np.ndarray:
    """c = A_pix · bend(p) + b_pix: a smooth invertible per-pixel colour map with mild mixing."""
    rng = np.random.default_rng(seed)
    a = 0.6 * np.eye(3) + rng.uniform(0.0, 0.08, (pixels, 3, 3))
    b = rng.uniform(0.02, 0.1, (pixels, 1, 3))
    return np.einsum("pij,pmj->pmi", a, bend(p)) + b


def spline_at(points: np.ndarray, centres: np.ndarray, coeffs: np.ndarray) -> np.ndarray:
    return tps.evaluate_splines(torch.tensor(points), torch.tensor(centres), torch.tensor(coeffs)).numpy()


# --- thin-plate splines -------------------------------------------------------------------------

@pytest.mark.parametrize("smoothing", [0.0, tps.SMOOTHING])
def test_tps_equals_scipy_rbf_interpolator(smoothing):
    """The fit is scipy's RBFInterpolator(kernel="thin_plate_spline", degree=1, smoothing=λ)."""
    rng = np.random.default_rng(1)
    centres = rng.random((3, 40, 3))
    values = rng.random((3, 40, 3))
    queries = rng.random((3, 25, 3))
    coeffs, _, degenerate = tps.fit_pixel_splines(centres, values, smoothing)
    ours = spline_at(queries, centres, coeffs)
    assert degenerate == 0
    for p in range(3):
        ref = RBFInterpolator(centres[p], values[p], kernel="thin_plate_spline", smoothing=smoothing,
                              degree=1)
        np.testing.assert_allclose(ours[p], ref(queries[p]), rtol=0, atol=1e-9)


def test_scale_invariant_smoothing_is_lambda_alpha_squared_per_pixel():
    """scale_invariant: each pixel's ridge is λ·α², α its mean centre distance over all n² pairs."""
    rng = np.random.default_rng(2)
    centres = rng.random((3, 30, 3)) * np.array([1.0, 0.5, 0.2])[:, None, None]  # three spreads
    values, queries = rng.random((3, 30, 3)), rng.random((3, 20, 3))
    coeffs, _, _ = tps.fit_pixel_splines(centres, values, 0.05, scale_invariant=True)
    ours = spline_at(queries, centres, coeffs)
    for p in range(3):
        alpha = np.linalg.norm(centres[p][:, None] - centres[p][None], axis=-1).mean()
        ref = RBFInterpolator(centres[p], values[p], kernel="thin_plate_spline",
                              smoothing=0.05 * alpha ** 2, degree=1)
        np.testing.assert_allclose(ours[p], ref(queries[p]), rtol=0, atol=1e-9)


def test_paper_smoothing_is_the_reimplementations_log2_kernel_with_ridge():
    """The paper profile's fit equals the public reimplementation's definition: kernel r² log₂ r,
    0.05·α² on its diagonal, affine part [1, R, G, B] (solved here directly)."""
    rng = np.random.default_rng(3)
    c, x, q = rng.random((1, 25, 3)), rng.random((1, 25, 3)), rng.random((1, 10, 3))
    n = c.shape[1]
    r = np.linalg.norm(c[0][:, None] - c[0][None], axis=-1)
    alpha = r.sum() / n ** 2
    k = np.where(r > 0, r * r * np.log2(np.where(r > 0, r, 1)), 0) + 0.05 * alpha ** 2 * np.eye(n)
    p = np.hstack([np.ones((n, 1)), c[0]])
    lhs = np.block([[k, p], [p.T, np.zeros((4, 4))]])
    w = np.linalg.solve(lhs, np.vstack([x[0], np.zeros((4, 3))]))
    rq = np.linalg.norm(q[0][:, None] - c[0][None], axis=-1)
    kq = np.where(rq > 0, rq * rq * np.log2(np.where(rq > 0, rq, 1)), 0)
    expected = kq @ w[:n] + np.hstack([np.ones((10, 1)), q[0]]) @ w[n:]
    coeffs, _, _ = tps.fit_pixel_splines(c, x, tps.PAPER_SMOOTHING, scale_invariant=True)
    np.testing.assert_allclose(spline_at(q, c, coeffs)[0], expected, rtol=0, atol=1e-9)


def test_profiles_choose_the_smoothing_and_say_so():
    paper, quick = make_config("paper", "tps"), make_config("quick", "tps")
    assert (paper.options.smoothing, paper.options.scale_invariant) == (tps.PAPER_SMOOTHING, True)
    assert (quick.options.smoothing, quick.options.scale_invariant) == (tps.SMOOTHING, False)
    assert make_config("paper", "tps-textured").options.scale_invariant
    assert make_config("quick", "tps-textured").options.smoothing == tps.SMOOTHING_TEXTURED
    assert (paper.options.label(), quick.options.label()) == ("λ = 0.0347·α²", "λ = 0.01")
    assert official_tag(paper) == "TPS_125_lambda0.0347alpha2"
    assert official_tag(make_config("quick", "tps-textured", n_train=250)) == "TPS_textured_250_lambda0.003"


def test_tps_interpolates_samples_exactly_without_smoothing():
    p = np.broadcast_to(grid(5), (4, 125, 3)).copy()
    c = planted_capture(p, 4, lambda q: q ** 1.3)
    coeffs, residual, _ = tps.fit_pixel_splines(c, p, 0.0)
    np.testing.assert_allclose(spline_at(c, c, coeffs), p, rtol=0, atol=1e-9)
    assert residual < 1e-9


def test_tps_reproduces_affine_maps_exactly_with_smoothing():
    """Affine maps have zero bending energy: smoothing leaves them untouched."""
    rng = np.random.default_rng(2)
    c = rng.random((2, 60, 3))
    m, b = rng.normal(size=(2, 3, 3)), rng.normal(size=(2, 1, 3))
    affine = lambda x: np.einsum("pij,pmj->pmi", m, x) + b  # noqa: E731
    coeffs, residual, _ = tps.fit_pixel_splines(c, affine(c), smoothing=0.1)
    q = rng.random((2, 30, 3)) * 1.5 - 0.25  # inside and outside the samples' hull
    np.testing.assert_allclose(spline_at(q, c, coeffs), affine(q), rtol=0, atol=1e-9)
    assert residual < 1e-9


def test_tps_reproduces_smooth_colour_map_from_plain_colours():
    """8×8 pixels, 5³ plain colours, c = A_pix (p + 0.05 p(1 − p)) + b_pix: inverse within 1e-3.

    (A power law p^1.3 cannot be interpolated that closely from 5 levels per channel by any
    kernel: about 2e-2, see the next test.)
    """
    bend = lambda q: q + 0.05 * q * (1 - q)  # noqa: E731
    p = np.broadcast_to(grid(5), (64, 125, 3)).copy()
    c = planted_capture(p, 64, bend)
    coeffs, _, _ = tps.fit_splines(c.astype(np.float32), p.astype(np.float32), 0.0, workers=1)
    held_out = np.random.default_rng(3).uniform(0.1, 0.9, (64, 200, 3))
    got = spline_at(planted_capture(held_out, 64, bend), c, coeffs.astype(np.float64))
    assert np.abs(got - held_out).max() < 1e-3


def test_tps_error_shrinks_with_denser_colour_samples():
    bend = lambda q: q ** 1.3  # noqa: E731
    held_out = np.random.default_rng(4).uniform(0.1, 0.9, (2, 300, 3))
    errors = []
    for levels in (5, 9):
        p = np.broadcast_to(grid(levels), (2, levels ** 3, 3)).copy()
        c = planted_capture(p, 2, bend)
        coeffs, _, _ = tps.fit_pixel_splines(c, p, 0.0)
        errors.append(np.abs(spline_at(planted_capture(held_out, 2, bend), c, coeffs) - held_out).max())
    assert errors[1] < 0.5 * errors[0]
    assert errors[1] < 1e-2


def test_tps_worker_pool_matches_one_process(monkeypatch):
    """Chunks solved by 2 forked workers come back in pixel order, equal to the in-process fit."""
    monkeypatch.setattr(tps, "_TASK_SIZE", 5 * 129 ** 2)  # 5 pixels per task
    rng = np.random.default_rng(5)
    p = np.broadcast_to(grid(5), (23, 125, 3)).astype(np.float32)
    noise = rng.normal(0, 0.002, (23, 125, 3))
    c = (planted_capture(p, 23, lambda q: q ** 2.2) + noise).astype(np.float32)
    pooled, residual, degenerate = tps.fit_splines(c, p, tps.SMOOTHING, workers=2)
    alone, alone_residual, _ = tps.fit_pixel_splines(c, p, tps.SMOOTHING)
    np.testing.assert_array_equal(pooled, alone.astype(np.float32))
    assert residual == pytest.approx(alone_residual / c.size, rel=1e-12)
    assert degenerate == 0


def test_tps_degenerate_pixel_falls_back_to_least_squares():
    """A pixel that always captures one colour (e.g. unseen) maps it to the mean sample."""
    c = np.full((1, 125, 3), 0.3)
    p = grid(5)[None]
    coeffs, _, degenerate = tps.fit_pixel_splines(c, p, tps.SMOOTHING)
    assert degenerate == 1
    np.testing.assert_allclose(spline_at(c[:, :1], c, coeffs), [[[0.5, 0.5, 0.5]]], atol=1e-9)


def test_tps_least_squares_is_the_minimum_norm_solution():
    """λ = 0 with duplicate centres (clipped captures) is singular: the fallback's solution equals
    the SVD's minimum-norm least-squares solution (an independent LAPACK driver)."""
    from scipy.linalg import lstsq

    rng = np.random.default_rng(3)
    c = rng.random((1, 40, 3))
    c[0, 30:] = c[0, 0]  # ten samples clip to the same captured colour
    p = rng.random((1, 40, 3))
    coeffs, _, degenerate = tps.fit_pixel_splines(c, p, 0.0)
    assert degenerate == 1
    r = np.linalg.norm(c[0, :, None] - c[0, None], axis=-1)
    lhs = np.zeros((44, 44))
    lhs[:40, :40] = r * r * np.log(np.where(r > 0, r, 1.0))
    lhs[:40, 40:43], lhs[:40, 43] = c[0], 1.0
    lhs[40:, :40] = lhs[:40, 40:].T
    rhs = np.zeros((44, 3))
    rhs[:40] = p[0]
    np.testing.assert_allclose(coeffs[0], lstsq(lhs, rhs, lapack_driver="gelsd")[0], atol=1e-8)


def test_tps_survives_a_channel_that_never_varies():
    """A surface without blue: the blue capture is constant, the affine part is rank deficient;
    the least-squares fit reproduces the map in the red–green plane and barely extrapolates
    along blue."""
    rg = grid(5)[::5, :2]  # the 25 (r, g) levels
    for blue in (0.0, 5 / 255):
        c = np.concatenate([rg, np.full((25, 1), blue)], axis=1)[None]
        p = np.concatenate([rg, np.full((25, 1), 0.5)], axis=1)[None]  # affine in (r, g)
        coeffs, _, degenerate = tps.fit_pixel_splines(c, p, tps.SMOOTHING)
        assert degenerate == 1
        np.testing.assert_allclose(spline_at(c, c, coeffs), p, atol=1e-9)
        off_plane = spline_at(c + np.array([0.0, 0.0, 0.2]), c, coeffs)
        assert np.abs(off_plane - p).max() < 0.01


def test_tps_condition_estimate_catches_collinear_colours():
    """Captures only on the gray axis (5 levels for the 125 plain colours): LU finds no zero pivot
    (it returns coefficients of about 1e16), but the condition estimate sends the pixel to least
    squares, which maps each gray level to its mean projector colour."""
    c = np.repeat(grid(5)[:, :1], 3, axis=1)[None]
    coeffs, _, degenerate = tps.fit_pixel_splines(c, grid(5)[None], tps.SMOOTHING)
    assert degenerate == 1
    assert np.abs(coeffs).max() < 1e3
    expected = np.stack([c[0, :, 0], np.full(125, 0.5), np.full(125, 0.5)], axis=1)[None]
    np.testing.assert_allclose(spline_at(c, c, coeffs), expected, atol=1e-6)


def test_tps_rejects_bad_samples():
    with pytest.raises(ValueError, match="one shape"):
        tps.fit_splines(np.zeros((2, 10, 3)), np.zeros((2, 9, 3)))
    with pytest.raises(ValueError, match="smoothing"):
        tps.fit_splines(np.zeros((2, 10, 3)), np.zeros((2, 10, 3)), smoothing=-1.0)


# --- colour mixing (Nayar et al.) ---------------------------------------------------------------

GAMMA = np.array([2.2, 1.8, 2.0])


def planted_mixing(pixels: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel V (diagonal-dominant, with crosstalk) and o keeping captures inside (0, 1)."""
    rng = np.random.default_rng(seed)
    v = np.diag([0.6, 0.55, 0.5]) + rng.uniform(0.0, 0.1, (pixels, 3, 3))
    o = rng.uniform(0.03, 0.12, (pixels, 3))
    return v, o


def plain_images(h: int, w: int, v: np.ndarray, o: np.ndarray, clip: bool = False):
    """The 125 uniform plain frames (125, 3, h, w) and their planted captures, float64."""
    x = grid(5)
    lin = np.broadcast_to(x ** GAMMA, (h * w, 125, 3))
    c = np.einsum("pij,pmj->pmi", v, lin) + o[:, None]
    if clip:
        c = np.clip(c, 0.0, 1.0)
    frames = torch.tensor(x).T[None, :, :, None, None].expand(1, 3, 125, h, w)[0].permute(1, 0, 2, 3)
    captures = torch.tensor(c).reshape(h, w, 125, 3).permute(2, 3, 0, 1)
    return frames.contiguous(), captures.contiguous()


def test_nayar_recovers_gamma_matrix_and_offset_exactly():
    v, o = planted_mixing(12)
    frames, captures = plain_images(3, 4, v, o)
    gamma = nayar.estimate_gamma(captures, frames)
    np.testing.assert_allclose(gamma, GAMMA, rtol=0, atol=1e-9)
    lin = torch.from_numpy(tps.pixel_samples(frames)).double() ** torch.from_numpy(gamma)
    per_pixel = captures.permute(2, 3, 0, 1).reshape(12, 125, 3)
    matrix, offset = nayar.fit_mixing(lin, per_pixel)
    np.testing.assert_allclose(matrix.numpy(), v, rtol=0, atol=1e-6)
    np.testing.assert_allclose(offset.numpy(), o, rtol=0, atol=1e-6)


def test_nayar_leaves_clipped_samples_out():
    """Bright pixels saturate the camera for some plain colours; the unclipped ones still pin V, o."""
    v, o = planted_mixing(6, seed=1)
    v *= 1.6  # white now captures above 1 in every channel
    _, captures = plain_images(2, 3, v, o, clip=True)
    per_pixel = captures.permute(2, 3, 0, 1).reshape(6, 125, 3)
    assert (per_pixel >= nayar.CLIP_HIGH).any(dim=1).all()
    lin = torch.tensor(np.broadcast_to(grid(5) ** GAMMA, (6, 125, 3)).copy())
    matrix, offset = nayar.fit_mixing(lin, per_pixel)
    np.testing.assert_allclose(matrix.numpy(), v, rtol=0, atol=1e-6)
    np.testing.assert_allclose(offset.numpy(), o, rtol=0, atol=1e-6)


def setup_data(frames: torch.Tensor, captures: torch.Tensor) -> SetupData:
    """A SetupData whose ref pairs are the plain colours (plus a gray frame); the rest is unused."""
    gray = torch.full_like(frames[:1], 0.5)
    pairs = PairSet(captures.float(), frames.float())
    ref = PairSet(torch.cat([captures, captures[:1]]).float(), torch.cat([frames, gray]).float())
    return SetupData("planted", None, pairs, pairs, ref, captures[:1].float())


def test_nayar_compensates_in_gamut_targets_exactly():
    h, w = 3, 4
    v, o = planted_mixing(h * w, seed=2)
    method = nayar.NayarMethod("cpu")
    method.fit(setup_data(*plain_images(h, w, v, o)), TrainConfig(method="nayar", options=NoOptions(), device="cpu"),
               progress=False)
    wanted = np.random.default_rng(6).uniform(0.05, 0.95, (h * w, 5, 3))  # projector inputs
    desired = np.einsum("pij,pmj->pmi", v, wanted ** GAMMA) + o[:, None]
    desired = torch.tensor(desired, dtype=torch.float32).reshape(h, w, 5, 3).permute(2, 3, 0, 1)
    got = method.predict(desired, desired[:1])
    expected = torch.tensor(wanted, dtype=torch.float32).reshape(h, w, 5, 3).permute(2, 3, 0, 1)
    assert got.dtype == torch.float32 and got.shape == (5, 3, h, w)
    torch.testing.assert_close(got, expected, rtol=0, atol=2e-5)  # float32 captures
    np.testing.assert_allclose(method.gamma.numpy(), GAMMA, rtol=0, atol=1e-4)


def test_nayar_needs_the_primary_ramps():
    levels = grid(5)
    keep = ~((levels[:, 1] == 0) & (levels[:, 2] == 0) & (levels[:, 0] > 0) & (levels[:, 0] < 1))
    with pytest.raises(ProcamError, match="ramp of primary R"):
        nayar.primary_ramps(levels[keep])


# --- through the registry -----------------------------------------------------------------------

def fit_config(method: str, **options) -> TrainConfig:
    """The method's default options (over ``options``), all pairs, CPU."""
    return TrainConfig(method=method, options=get_method(method).options(**options), eval_batch=3,
                       device="cpu", n_train=None, n_test=None)


@pytest.mark.parametrize("name", ["tps", "tps-textured", "nayar"])
@pytest.mark.slow
def test_method_trains_into_a_run_and_beats_uncompensated(name, setup_dir, data, tmp_path):
    """The synthetic setup (capture = 0.15 + 0.7 · frame · albedo) is per-pixel affine, so every
    baseline compensates it up to 8-bit quantisation."""
    out = tmp_path / name
    metrics = train_run(setup_dir, fit_config(name), out, progress=False)
    written = {p.name for p in out.iterdir()}
    assert {"config.json", "metrics.json", "loss.csv", "examples.png", STATE[name]} <= written
    assert json.loads((out / "metrics.json").read_text()) == metrics
    assert metrics["psnr"] > metrics["uncompensated"]["psnr"] + 20
    assert metrics["psnr"] > 45
    assert metrics["batch"] == (16 if name == "tps-textured" else 125)

    method, config = load_run(out, "cpu")
    assert type(method) is get_method(name) and config["train"]["method"] == name
    fresh = get_method(name)("cpu")
    fresh.fit(data, fit_config(name), progress=False)
    torch.testing.assert_close(method.predict(data.test.captures, data.surface),
                               fresh.predict(data.test.captures, data.surface), rtol=0, atol=0)


@pytest.mark.parametrize("name", ["tps", "nayar"])
def test_save_load_round_trip_is_identical(name, data, tmp_path):
    method = get_method(name)("cpu")
    method.fit(data, fit_config(name), progress=False)
    method.save(tmp_path)
    loaded = get_method(name).load(tmp_path, "cpu")
    before = method.predict(data.test.captures, data.surface, batch_size=3)
    assert torch.equal(before, loaded.predict(data.test.captures, data.surface, batch_size=3))
    # Another batch size regroups the float32 products: equal up to rounding.
    torch.testing.assert_close(before, loaded.predict(data.test.captures, data.surface, batch_size=2),
                               rtol=0, atol=1e-6)
    assert before.min() >= 0 and before.max() <= 1


@pytest.mark.parametrize("name", ["tps", "nayar"])
def test_load_refuses_pickles_and_bad_shapes(name, tmp_path):
    path = tmp_path / STATE[name]
    np.savez(path, centres=np.array([{"x": 1}], dtype=object), gamma=np.array([{"x": 1}], dtype=object))
    with pytest.raises(ProcamError, match=str(path)):
        get_method(name).load(tmp_path, "cpu")
    arrays = ({"centres": np.zeros((4, 5, 3)), "coeffs": np.zeros((4, 8, 3)), "size": np.array([2, 2]),
               "smoothing": np.float64(0.01)} if name == "tps" else
              {"gamma": np.ones(3), "matrix": np.zeros((4, 3, 3)), "offset": np.zeros((3, 3)),
               "size": np.array([2, 2])})
    np.savez(path, **arrays)
    with pytest.raises(ProcamError, match="inconsistent shapes"):
        get_method(name).load(tmp_path, "cpu")
    whole = path.read_bytes()
    for damaged in (whole[:len(whole) // 2], b"PK\x03\x04" + b"\0" * 40, b""):  # cut, broken zip, empty
        path.write_bytes(damaged)
        with pytest.raises(ProcamError, match=re.escape(f"{path}: cannot read")):
            get_method(name).load(tmp_path, "cpu")


def test_predict_checks_the_image_size(data):
    method = get_method("nayar")("cpu")
    method.fit(data, fit_config("nayar"), progress=False)
    with pytest.raises(ProcamError, match="fitted for"):
        method.predict(data.test.captures[:, :, :16], data.surface)


def test_tps_textured_takes_a_seeded_subset_beyond_max_samples(data):
    method = tps.TPSTexturedMethod("cpu")
    first = method.training_pairs(data, fit_config("tps-textured", max_samples=8))
    again = method.training_pairs(data, fit_config("tps-textured", max_samples=8))
    assert len(first) == 8 and torch.equal(first.captures, again.captures)
    rows = {tuple(f.flatten()[:64].tolist()) for f in data.train.frames}
    assert all(tuple(f.flatten()[:64].tolist()) in rows for f in first.frames)
    other_seed = method.training_pairs(data, replace(fit_config("tps-textured", max_samples=8), seed=1))
    assert not torch.equal(first.captures, other_seed.captures)
    every = method.training_pairs(data, fit_config("tps-textured"))
    assert len(every) == len(data.train)


@pytest.mark.parametrize("name", ["tps", "tps-textured"])
def test_tps_fit_uses_the_smoothing_option(name, data, tmp_path):
    """``smoothing`` comes from ``cfg.options``: it is the λ of the fit and is saved with the state;
    a larger λ leaves larger residuals at the samples."""
    fitted = {}
    for smoothing in (0.0, 0.5):
        method = get_method(name)("cpu")
        stats = method.fit(data, fit_config(name, smoothing=smoothing, workers=1), progress=False)
        assert method.smoothing == smoothing
        method.save(tmp_path)
        assert get_method(name).load(tmp_path, "cpu").smoothing == smoothing
        fitted[smoothing] = stats.final_loss
    assert fitted[0.0] < 1e-4 < fitted[0.5]


@pytest.mark.parametrize("options, message", [
    (dict(smoothing=-1.0), "option smoothing = -1.0: expected a number >= 0"),
    (dict(smoothing=float("inf")), "option smoothing = inf: expected 0 or a number from 1.18e-38 to 3.4e+38"),
    (dict(scale_invariant=1), "option scale_invariant = 1: expected true or false"),
    (dict(workers=0), "option workers = 0: expected a positive integer"),
    (dict(max_samples=3), "option max_samples = 3: expected an integer >= 4"),
])
def test_tps_options_are_checked(options, message):
    with pytest.raises(ProcamError, match=re.escape(message)):
        tps.TPSTexturedOptions(**options)


def test_the_spline_solves_run_on_one_blas_thread(monkeypatch):
    """OpenBLAS's threads made a singular pixel's 129 × 129 least squares slower (4.9× on 2 free
    cores, 20-80× with another job beside): the fit sets every loaded OpenBLAS to one thread, and
    restores it after."""
    import compensation.methods.tps as tps
    from sim.blas import openblas_threads

    before = openblas_threads()
    assert before  # NumPy's and SciPy's wheels each bundle an OpenBLAS
    seen = []
    real = tps.fit_pixel_splines

    def spy(*args, **kwargs):
        seen.append(openblas_threads())
        return real(*args, **kwargs)

    monkeypatch.setattr(tps, "fit_pixel_splines", spy)
    rng = np.random.default_rng(0)
    centres, values = rng.random((8, 6, 3)), rng.random((8, 6, 3))
    centres[:, :2] = 0.0  # two clipped samples: singular at λ = 0, solved by least squares
    coeffs, _, degenerate = tps.fit_splines(centres, values, 0.0, workers=1)
    assert degenerate == 8 and np.isfinite(coeffs).all()
    assert seen and all(threads == [1] * len(before) for threads in seen)
    assert openblas_threads() == before


def test_the_tps_benchmark_times_both_arms():
    """``benchmarks/tps.py``: each kind of pixel with both arms' medians and their ratio."""
    from helpers import run_benchmark

    proc = run_benchmark("tps.py", "--pixels", "24", "--samples", "12", "--rounds", "1", "--workers", "1")
    assert proc.returncode == 0, proc.stderr
    rows = re.findall(r"^  (regular|singular) \(λ = ([\d.e-]+)\): OpenBLAS threads as loaded ([\d.]+), "
                      r"one thread ([\d.]+), speed-up ([\d.]+)×$", proc.stdout, flags=re.M)
    assert [(kind, float(lam)) for kind, lam, *_ in rows] == [("regular", 0.01), ("singular", 0.0)], proc.stdout
    for *_, default, one, ratio in rows:
        assert float(default) > 0 and float(one) > 0
        assert float(ratio) == pytest.approx(float(default) / float(one), rel=0.01, abs=0.006)
