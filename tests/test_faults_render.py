"""Fault injection into `procam render` and `procam bench-sim`: hostile inputs are refused before
anything is written, with a message naming the file, key or value and no traceback; a render
killed (SIGKILL) at any point resumes to the bytes of an uninterrupted run; a resume trusts no
file or record it cannot check."""
from __future__ import annotations

import fcntl
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from compensation.cli import main
from helpers import TINY_RENDER as ARGS
from helpers import interrupted_render, tiny_setup, tiny_setup_file, tiny_toml
from sim import camera, registration
from sim.dataset import FrameSpec
from sim.errors import ProcamError
from sim.io import read_png, write_png
from sim.options import option_fields, spec_of
from sim.setup import load_setup
from sim.setup.schema import SECTIONS
from sim.variant import check_forced

REPO = Path(__file__).resolve().parents[1]
VOLATILE = ("timings_s", "captures_per_second", "captures_this_run")
"""meta.json keys that differ between two runs of the same render."""


def _snapshot(root: Path) -> dict[str, bytes]:
    """Every file under ``root`` (relative path -> bytes)."""
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def _assert_same_dataset(root: Path, reference: Path) -> None:
    """The same files with the same bytes, meta.json up to its timings."""
    got, want = _snapshot(root), _snapshot(reference)
    assert sorted(got) == sorted(want)
    for name in want:
        if name.endswith("meta.json"):
            a, b = json.loads(got[name]), json.loads(want[name])
            assert {k: v for k, v in a.items() if k not in VOLATILE} == \
                   {k: v for k, v in b.items() if k not in VOLATILE}, name
        else:
            assert got[name] == want[name], name


def _refused(capsys, argv: list[str], *fragments: str) -> str:
    """Run the CLI in this process: exit status 2, the message holds every fragment."""
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    for fragment in fragments:
        assert fragment in err, (fragment, err)
    return err


def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(REPO), "OMP_WAIT_POLICY": "PASSIVE"}


KILLER = """
import itertools, os, signal, sys
from pathlib import Path
import sim.io

pattern, nth, argv = sys.argv[1], int(sys.argv[2]), sys.argv[3:]
write, calls = sim.io.atomic_write, itertools.count(1)

def atomic_write(path, data):
    path = Path(path)
    if path.match(pattern) and next(calls) == nth:  # die half-way through writing this file
        path.parent.mkdir(parents=True, exist_ok=True)
        part = data.encode() if isinstance(data, str) else data
        (path.parent / f".{path.name}.killed.tmp").write_bytes(part[:len(part) // 2])
        os.kill(os.getpid(), signal.SIGKILL)
    write(path, data)

sim.io.atomic_write = atomic_write
from compensation.cli import main
sys.exit(main(argv))
"""


def _killed_render(argv: list[str], pattern: str, nth: int = 1) -> None:
    """`procam render` in a child process (umask 027) killed with SIGKILL while writing the
    ``nth`` file whose path matches ``pattern``."""
    proc = subprocess.run([sys.executable, "-c", KILLER, pattern, str(nth), *argv], env=_env(),
                          capture_output=True, text=True, preexec_fn=lambda: os.umask(0o027))
    assert proc.returncode == -9, proc.stderr


@pytest.fixture
def reference(tiny_render) -> Path:
    """An uninterrupted render of the tiny setup: its root folder (the setup file beside it)."""
    return tiny_render / "data"


def _copy(reference: Path, tmp_path: Path) -> Path:
    root = tmp_path / "data"
    shutil.copytree(reference, root)
    return root


# --------------------------------------------------------------- setups that capture nothing useful

@pytest.mark.parametrize("pose", [{"projector": {"look_at": [4.0, 0.0, 0.5]}},  # projector aimed away
                                  {"camera": {"look_at": [3.0, 0.0, 0.0]}}])  # camera aimed away
def test_setup_that_sees_no_projection_is_refused_before_rendering(tmp_path, capsys, pose):
    setup = tiny_setup_file(tmp_path, **pose)
    _refused(capsys, ["render", str(setup), "--out", str(tmp_path / "data"), *ARGS],
             'setup "tiny"', "only 0.0% of the projector image", "at least 50%", "look_at")
    assert not (tmp_path / "data").exists()


def test_every_setup_of_a_suite_is_checked_before_the_first_is_rendered(tmp_path, capsys):
    tiny_setup_file(tmp_path)
    suite = tmp_path / "suite.toml"
    suite.write_text('base = "tiny.toml"\n[[setup]]\nname = "good"\n[[setup]]\nname = "away"\n'
                     "projector = { look_at = [4.0, 0.0, 0.5] }\n")
    _refused(capsys, ["render", str(suite), "--out", str(tmp_path / "data"), *ARGS], 'setup "away"')
    assert not (tmp_path / "data").exists()


def test_shipped_setups_see_the_whole_projection():
    from sim.setup import load_setups

    assert registration.check_visible(load_setups("ideal")[0], (32, 32)) == 1.0


# ------------------------------------------------------------- inputs checked before anything is written

def _bad_texture(tmp_path: Path, content: bytes) -> list[str]:
    (tmp_path / "tex.png").write_bytes(content)
    return [str(tiny_setup_file(tmp_path, texture="tex.png"))]


def _image_folder(tmp_path: Path, broken: bool) -> list[str]:
    folder = tmp_path / "frames"
    for name in ("a.png", "b.png") + (("c.png",) if broken else ()):
        write_png(folder / name, np.full((8, 8, 3), 100, np.uint8))
    if broken:
        (folder / "c.png").write_bytes((folder / "c.png").read_bytes()[:10])
    return [str(tiny_setup_file(tmp_path)), "--images", str(folder)]


def _latin1_setup(tmp_path: Path) -> list[str]:
    path = tmp_path / "latin.toml"
    path.write_bytes('name = "café"\n'.encode("latin-1"))
    return [str(path)]


BAD_INPUTS = {
    "texture that is text": (lambda t: _bad_texture(t, b"not an image"),
                             ["tiny.toml", 'surface.texture = "tex.png"', "cannot read image"]),
    "texture cut after its header": (lambda t: _bad_texture(t, b"\x89PNG\r\n\x1a\n\x00\x00"),
                                     ["tiny.toml", 'surface.texture = "tex.png"', "tex.png"]),
    "--images with a damaged file": (lambda t: _image_folder(t, broken=True),
                                     ["c.png", "cannot read image"]),
    "--images with too few files": (lambda t: _image_folder(t, broken=False),
                                    ["frames", "found 2 image files", "need 3"]),
    "--n-train -5": (lambda t: [str(tiny_setup_file(t)), "--n-train", "-5"], ["--n-train", "-5", ">= 1"]),
    "--n-test 0": (lambda t: [str(tiny_setup_file(t)), "--n-test", "0"], ["--n-test", "0", ">= 1"]),
    "--frame-seed -1": (lambda t: [str(tiny_setup_file(t)), "--frame-seed", "-1"], ["--frame-seed", "-1"]),
    "--spp 0": (lambda t: [str(tiny_setup_file(t)), "--spp", "0"], ["--spp", "= 0", "from 1 to 65536"]),
    "--fidelity direct on a corner": (lambda t: ["corner", "--fidelity", "direct"],
                                      ['fidelity "direct"', "inter-reflection"]),
    "setup file not UTF-8": (lambda t: _latin1_setup(t), ["latin.toml", "not valid TOML"]),
    "--size 100000": (lambda t: [str(tiny_setup_file(t)), "--size", "100000"], ["--size", "100000", "<= 4096"]),
    "--n-train 1e9": (lambda t: [str(tiny_setup_file(t)), "--n-train", "1000000000"],
                      ["--n-train 1000000000", "GiB in memory", "half of this machine's memory"]),
    "--spp 1e9": (lambda t: [str(tiny_setup_file(t)), "--spp", "1000000000"], ["--spp", "from 1 to 65536"]),
    "--frame-seed 2**40": (lambda t: [str(tiny_setup_file(t)), "--frame-seed", str(2 ** 40)],
                           ["--frame-seed", "<= 4294967295"]),
    "render.max_depth 2**63-1": (lambda t: [str(tiny_setup_file(t, render={"max_depth": 2 ** 63 - 1}))],
                                 ["render.max_depth", "in [2, 64]"]),
    "render.seed 2**62": (lambda t: [str(_big_seed(t))], ["render.seed", "in [0, 4.29497e+09]"]),
    "--n-train 2**70": (lambda t: [str(tiny_setup_file(t)), "--n-train", str(2 ** 70)],
                        [f"--n-train {2 ** 70}", "GiB in memory", "half of this machine's memory"]),
    "--n-test 2**70": (lambda t: [str(tiny_setup_file(t)), "--n-test", str(2 ** 70)],
                       [f"--n-test {2 ** 70}", "GiB in memory"]),
    "--frame-seed 2**70": (lambda t: [str(tiny_setup_file(t)), "--frame-seed", str(2 ** 70)],
                           ["--frame-seed", "<= 4294967295"]),
    "--spp 2**63": (lambda t: [str(tiny_setup_file(t)), "--spp", str(2 ** 63)], ["--spp", "from 1 to 65536"]),
    "--size 8x100000": (lambda t: [str(tiny_setup_file(t)), "--size", "8x100000"],
                        ["--size", "100000", "<= 4096"]),
}


def _big_seed(folder):
    """A setup file whose render seed does not fit 32 bits (TOML integers stop at 64 bits)."""
    path = tiny_setup_file(folder)
    path.write_text(path.read_text().replace("[render]", f"[render]\nseed = {2 ** 62}"))
    return path


@pytest.mark.parametrize("case", BAD_INPUTS)
def test_bad_input_is_refused_and_writes_nothing(tmp_path, capsys, case):
    make, fragments = BAD_INPUTS[case]
    argv = make(tmp_path)
    _refused(capsys, ["render", argv[0], "--out", str(tmp_path / "data"), *ARGS, *argv[1:]], *fragments)
    assert not (tmp_path / "data").exists()


def _setup_keys():
    """Every key of a setup file: (section, key, its spec, the keys it needs beside it: a surface's
    own key its geometry)."""
    for section, cls in SECTIONS.items():
        for f in option_fields(cls):
            spec = spec_of(f)
            if spec.kind == "variant":
                for geometry, options in spec.variants.items():
                    yield from ((section, g.name, spec_of(g), {"geometry": geometry})
                            for g in option_fields(options))
            else:
                yield section, f.name, spec, {}


def _filled(spec, value):
    """``value`` in the shape a key of ``spec`` holds (a number, every entry of a vector or matrix)."""
    if spec.kind == "vector":
        return [value] * spec.length
    return [[value] * spec.length for _ in range(spec.length)] if spec.kind == "matrix" else value


def _label(value) -> str:
    """A test id for a number: ``1e+39``, or ``10**400`` for a huge integer (no float holds it)."""
    return f"{value:g}" if isinstance(value, float) else f"10**{len(str(value)) - 1}"


NUMBER_TRIES = {f"{section}.{key}={_label(value)}": (section, key, spec, extra, value)
                for section, key, spec, extra in _setup_keys() if spec.kind in ("number", "vector", "matrix")
                and not spec.integer for value in (1e39, 1e300, -1e39, 10 ** 400, 1e-40)}
"""Every key holding numbers, at values finite in float64 but not in float32 (captures are
computed in float32), an integer too large for a float (TOML integers have no limit) and a number
that float32 rounds to 0."""
INTEGER_TRIES = {f"{section}.{key}={value}": (section, key, spec, extra, value)
                 for section, key, spec, extra in _setup_keys() if spec.kind == "integer" or spec.integer
                 for value in (2 ** 63 - 1, -2 ** 63)}
"""Every key holding integers, at the ends of what a TOML integer holds."""


@pytest.mark.parametrize("key", [*NUMBER_TRIES, *INTEGER_TRIES])
def test_every_number_key_refuses_what_float32_or_its_range_cannot_hold(tmp_path, capsys, key):
    section, name, spec, extra, value = {**NUMBER_TRIES, **INTEGER_TRIES}[key]
    setup = tiny_setup_file(tmp_path, **{section: {**extra, name: _filled(spec, value)}})
    _refused(capsys, ["render", str(setup), "--out", str(tmp_path / "data"), *ARGS], f"{section}.{name} = ",
             ": expected ")
    assert not (tmp_path / "data").exists()


CONSTANT_CAPTURES = {
    "projector.brightness=1e-30": {"projector": {"brightness": 1e-30}},
    "projector.brightness=1e30": {"projector": {"brightness": 1e30}},
    "projector.mixing=1e30": {"projector": {"mixing": [[1e30, 0.0, 0.0], [0.0, 1e30, 0.0], [0.0, 0.0, 1e30]]}},
    "camera.exposure=1e-30": {"camera": {"exposure": 1e-30}},
    "camera.exposure=1e30": {"camera": {"exposure": 1e30}},
    "camera.white_balance=1e-30": {"camera": {"white_balance": [1e-30] * 3}},
    "camera.white_balance=1e30": {"camera": {"white_balance": [1e30] * 3}},
    "camera.shot_noise=1e30": {"camera": {"shot_noise": 1e30}},
    "camera.read_noise=1e30": {"camera": {"read_noise": 1e30}},
    "camera.aperture_radius=1e30 traced": {"camera": {"aperture_radius": 1e30, "defocus": "ray"}},
    "camera.focus_distance=1e-30 traced": {"camera": {"aperture_radius": 0.01, "focus_distance": 1e-30,
                                                      "defocus": "ray"}},
    "camera.position=1e30 away": {"camera": {"position": [0.25, 0.0, 1e30]}},
    "surface.albedo_scale=1e-30": {"surface": {"albedo_scale": 1e-30}},
    "surface.tint=0": {"surface": {"tint": [0.0] * 3}},
    "surface.size=1e30": {"surface": {"size": [1e30, 1e30]}},
    "ambient.radiance=1e30": {"ambient": {"radiance": [1e30] * 3}},
    "ambient.intensity=1e30": {"ambient": {"temperature": 6500.0, "intensity": 1e30}},
}
"""Values every range admits that make the captures independent of the projector: no light of it
reaches the camera, every pixel clips, or noise drowns it."""


@pytest.mark.parametrize("case", CONSTANT_CAPTURES)
def test_captures_independent_of_the_projector_are_refused_with_the_contrast(tmp_path, capsys, case):
    setup = tiny_setup_file(tmp_path, registration={"method": "exact"}, **CONSTANT_CAPTURES[case])
    data = tmp_path / "data"
    _refused(capsys, ["render", str(setup), "--out", str(data), *ARGS],
             "setup 'tiny': the captures do not respond to the projector", "8-bit levels on average")
    assert not (data / "tiny" / "meta.json").exists() and not (data / "tiny" / "setup.toml").exists()


DEAD_CHANNELS = {
    "camera.white_balance red=1e-30": ({"camera": {"white_balance": [1e-30, 1.0, 1.0]}}, "R channel(s)"),
    "projector.mixing red row 0": (
        {"projector": {"mixing": [[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]}}, "R channel(s)"),
    "projector.mixing red=3e38": (
        {"projector": {"mixing": [[3e38, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]}}, "R channel(s)"),
    "camera.white_balance blue=1e30": ({"camera": {"white_balance": [1.0, 1.0, 1e30]}}, "B channel(s)"),
}
"""Values that leave one colour channel independent of the projector (dark, or clipped on every
frame) while the others respond: the mean over the channels passed, and such a dataset rendered
with exit status 0."""


@pytest.mark.parametrize("case", DEAD_CHANNELS)
def test_a_channel_that_does_not_respond_to_the_projector_is_refused(tmp_path, capsys, case):
    keys, channel = DEAD_CHANNELS[case]
    setup = tiny_setup_file(tmp_path, registration={"method": "exact"}, **keys)
    data = tmp_path / "data"
    _refused(capsys, ["render", str(setup), "--out", str(data), *ARGS],
             f"setup 'tiny': the captures' {channel} do not respond to the projector", "in each channel")
    assert not (data / "tiny").exists()


def test_the_exposure_rule_on_a_black_white_is_refused_in_one_line(tmp_path, capsys):
    """No light from the projector or the room: the rule has nothing to expose for (a traceback
    before)."""
    setup = tiny_setup_file(tmp_path, registration={"method": "exact"}, camera={"exposure_mode": "rule"},
                            projector={"mixing": [[0.0] * 3] * 3}, ambient={"radiance": [0.0] * 3})
    data = tmp_path / "data"
    _refused(capsys, ["render", str(setup), "--out", str(data), *ARGS],
             'camera.exposure_mode = "rule": the capture of plain white is black', "projector.mixing")
    assert not (data / "tiny").exists()


@pytest.mark.parametrize("projector", [{"aperture": 1e30}, {"aperture": 0.01, "focus_distance": 1e-30}],
                         ids=["aperture=1e30", "focus_distance=1e-30"])
@pytest.mark.slow
def test_a_defocus_disk_wider_than_the_panel_is_refused_before_its_kernel(tmp_path, capsys, projector):
    """The disk kernel's size grows as the square of its diameter: a disk of 1e16 pixels is
    refused, naming the keys and the limit, before its kernel is made; the corrected setup renders
    into the same folder."""
    data = tmp_path / "data"
    _refused(capsys, ["render", str(tiny_setup_file(tmp_path, projector=projector)), "--out", str(data), *ARGS],
             f"projector.aperture = {projector['aperture']:g} m", "expected at most the panel's 64 pixels")
    assert not (data / "tiny" / "setup.toml").exists()
    assert main(["render", str(tiny_setup_file(tmp_path)), "--out", str(data), *ARGS]) == 0


@pytest.mark.parametrize("camera", [{"aperture_radius": 1e30}, {"aperture_radius": 0.01, "focus_distance": 1e-30}],
                         ids=["aperture_radius=1e30", "focus_distance=1e-30"])
def test_a_camera_defocus_disk_too_wide_is_refused_before_its_kernel(tmp_path, capsys, camera):
    """The same for the camera's defocus in image space (``camera.defocus = "image"``): refused
    before the scene is built, nothing written."""
    data = tmp_path / "data"
    _refused(capsys, ["render", str(tiny_setup_file(tmp_path, camera=camera)), "--out", str(data), *ARGS],
             f"camera.aperture_radius = {camera['aperture_radius']:g} m", "expected at most 1024",
             'camera.defocus = "ray"')
    assert not (data / "tiny" / "setup.toml").exists()


def test_output_root_that_is_a_file_is_refused(tmp_path, capsys):
    (tmp_path / "data").write_text("a file")
    _refused(capsys, ["render", str(tiny_setup_file(tmp_path)), "--out", str(tmp_path / "data"), *ARGS],
             str(tmp_path / "data"), "cannot write the dataset root")
    assert (tmp_path / "data").read_text() == "a file"


@pytest.mark.parametrize("option", [["--window", "0"], ["--repeats", "0"], ["--ref-spp", "0"],
                                    ["--spp", "4,0"]])
def test_bench_sim_refuses_options_below_one(tmp_path, capsys, option):
    argv = ["bench-sim", str(tiny_setup_file(tmp_path)), "--out", str(tmp_path / "bench"), "--quiet",
            "--classes", "smooth", "--ref-spp", "4", "--spp", "1", *option]
    if option[0] == "--spp":
        with pytest.raises(SystemExit) as exit_:  # an argparse type: usage and the value
            main(argv)
        assert exit_.value.code == 2 and "'4,0'" in capsys.readouterr().err
    else:
        _refused(capsys, argv, f"{option[0]} 0", ">= 1")
    assert not (tmp_path / "bench").exists()


@pytest.mark.parametrize("option", [["--ref-spp", str(10 ** 9)], ["--spp", str(2 ** 63)],
                                    ["--repeats", str(2 ** 70)], ["--classes", "smooth,smooth"],
                                    ["--classes", ","]], ids=" ".join)
def test_bench_sim_refuses_huge_or_repeated_values_before_measuring(tmp_path, capsys, option):
    argv = ["bench-sim", str(tiny_setup_file(tmp_path)), "--out", str(tmp_path / "bench"), "--quiet",
            "--classes", "smooth", "--ref-spp", "4", "--spp", "1", "--window", "8", "--repeats", "1", *option]
    expected = {"--ref-spp": "<= 65536", "--spp": "<= 65536", "--repeats": "<= 1000"}.get(option[0], "--classes")
    _refused(capsys, argv, f"{option[0]} ", expected)
    assert not (tmp_path / "bench").exists()


def test_bench_sim_refuses_a_repeated_spp(capsys, tmp_path):
    with pytest.raises(SystemExit) as exit_:  # an argparse type: usage and the value
        main(["bench-sim", str(tiny_setup_file(tmp_path)), "--out", str(tmp_path / "bench"), "--spp", "4,4"])
    assert exit_.value.code == 2 and "'4,4'" in capsys.readouterr().err


@pytest.mark.parametrize("name, fragment", [("bogus", "not a Mitsuba variant"),
                                            ("scalar_spectral", "procam renders RGB"),
                                            ("llvm_ad_mono", "procam renders RGB")])
def test_unusable_variant_is_refused(name, fragment):
    with pytest.raises(ProcamError, match=f"PROCAM_VARIANT='{name}': {fragment}"):
        check_forced(name)


def test_cuda_variant_without_a_gpu_is_refused():
    import drjit as dr

    if dr.has_backend(dr.JitBackend.CUDA):
        pytest.skip("a CUDA device is present")
    with pytest.raises(ProcamError, match="CUDA backend is not available here"):
        check_forced("cuda_ad_rgb")


@pytest.mark.slow
def test_bad_variant_from_the_command_line(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "compensation.cli", "render", str(tiny_setup_file(tmp_path)),
                           "--out", str(tmp_path / "data"), *ARGS],
                          env={**_env(), "PROCAM_VARIANT": "bogus"}, capture_output=True, text=True)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert "PROCAM_VARIANT='bogus'" in proc.stderr and "llvm_ad_rgb" in proc.stderr
    assert not (tmp_path / "data").exists()


# ------------------------------------------------------------------------ kill -9, resume, same bytes

@pytest.mark.slow
def test_killed_at_every_stage_resumes_to_the_same_bytes(reference, tmp_path, capsys):
    root = tmp_path / "data"
    argv = ["render", str(tiny_setup_file(tmp_path)), "--out", str(root), *ARGS]
    _killed_render(argv, "data/ref/img_*.png", nth=5)  # while writing the shared frames
    assert json.loads((root / "frames.json").read_text())["source"]["seed"] == 0  # written first
    assert not (root / "tiny").exists()
    _killed_render(argv, "warp/*/img_*.png", nth=10)  # while writing captures
    assert (root / "tiny" / "render.json").exists() and not (root / "tiny" / "meta.json").exists()
    # resumed with another frame seed: refused (captures depend on the frames), nothing touched
    before = _snapshot(root)
    _refused(capsys, [*argv, "--frame-seed", "7"], str(root / "frames.json"), "'seed': 0", "'seed': 7")
    assert _snapshot(root) == before
    _killed_render(argv, "meta.json")  # while writing the record of a finished setup
    assert list(root.rglob(".*.tmp")) and not (root / "tiny" / "meta.json").exists()
    assert main(argv) == 0
    _assert_same_dataset(root, reference)  # leftover temporary files removed too
    for path in [root, *root.rglob("*")]:  # all but meta.json written under umask 027
        assert path.name == "meta.json" or path.stat().st_mode & 0o027 == 0, path


@pytest.mark.slow
def test_killed_with_raw_resumes_without_it_to_the_same_warped_bytes(reference, tmp_path):
    """A --raw render killed half-way and resumed without --raw: the captures it had finished are
    warped from their raw files, the others rendered, every warped capture the bytes of an
    uninterrupted run; the raw captures of half the setup are not recorded as kept. With --raw
    again, the rest are rendered: the whole dataset of an uninterrupted --raw run."""
    root = tmp_path / "data"
    argv = ["render", str(tiny_setup_file(tmp_path)), "--out", str(root), *ARGS]
    _killed_render([*argv, "--raw"], "raw/*/img_*.png", nth=64)
    raw = sorted((root / "tiny" / "cam" / "raw").rglob("img_*.png"))
    assert 60 <= len(raw) < 126 + 2 + 1
    for victim in (root / "tiny" / "cam" / "warp" / "ref").glob("img_000*.png"):
        victim.unlink()  # their raw files are there: warped again, not rendered
    assert main(argv) == 0
    meta = json.loads((root / "tiny" / "meta.json").read_text())
    assert meta["raw"] is False and meta["captures_this_run"] > 126 + 2 + 1 - len(raw)
    assert sorted((root / "tiny" / "cam" / "raw").rglob("img_*.png")) == raw
    warped = sorted((reference / "tiny" / "cam" / "warp").rglob("img_*.png"))
    for path in warped:
        assert (root / path.relative_to(reference)).read_bytes() == path.read_bytes(), path
    assert main([*argv, "--raw"]) == 0
    full = tmp_path / "full"
    assert main(["render", str(tmp_path / "tiny.toml"), "--out", str(full), *ARGS, "--raw"]) == 0
    _assert_same_dataset(root, full)


def test_damaged_files_are_written_again(reference, tmp_path):
    root = _copy(reference, tmp_path)
    (root / "tiny" / "meta.json").unlink()  # an unfinished setup
    for rel, keep in (("tiny/cam/warp/train/img_0001.png", 0.5), ("tiny/cam/warp/test/img_0001.png", -1),
                      ("train/img_0002.png", 0.3), ("tiny/cam/warp/ref/img_0126.png", 0)):
        path = root / rel
        data = path.read_bytes()
        path.write_bytes(data[:keep] if keep <= 0 else data[:int(len(data) * keep)])
    write_png(root / "tiny/cam/warp/ref/img_0002.png", np.zeros((5, 5, 3), np.uint8))  # wrong size
    assert main(["render", str(reference.parent / "tiny.toml"), "--out", str(root), *ARGS]) == 0
    _assert_same_dataset(root, reference)


@pytest.mark.slow
def test_damaged_raw_captures_are_written_again_with_raw(reference, tmp_path):
    """With --raw a damaged raw capture is a capture to render again; without, a setup does not
    need it."""
    root = _copy(reference, tmp_path)
    assert main(["render", str(reference.parent / "tiny.toml"), "--out", str(root), *ARGS, "--raw"]) == 0
    full = _copy(root, tmp_path / "full")
    (root / "tiny" / "meta.json").unlink()
    victim = root / "tiny/cam/raw/train/img_0001.png"
    victim.write_bytes(victim.read_bytes()[:100])
    write_png(root / "tiny/cam/raw/ref/img_0002.png", np.zeros((5, 5, 3), np.uint8))  # wrong size
    assert main(["render", str(reference.parent / "tiny.toml"), "--out", str(root), *ARGS, "--raw"]) == 0
    assert json.loads((root / "tiny" / "meta.json").read_text())["captures_this_run"] == 2
    _assert_same_dataset(root, full)


def test_frame_of_another_source_is_refused(reference, tmp_path, capsys):
    root = _copy(reference, tmp_path)
    shutil.copy(root / "ref" / "img_0001.png", root / "train" / "img_0001.png")
    before = _snapshot(root)
    _refused(capsys, ["render", str(reference.parent / "tiny.toml"), "--out", str(root), *ARGS],
             str(root / "train" / "img_0001.png"), "another frame")
    assert _snapshot(root) == before


# ------------------------------------------------------------------------------ records checked on resume

def _edit_json(path: Path, **changes) -> None:
    path.write_text(json.dumps({**json.loads(path.read_text()), **changes}))


@pytest.mark.parametrize("finished", [False, True])
def test_resume_under_another_variant_is_refused(reference, tmp_path, capsys, finished):
    """A setup started (or finished) under another Mitsuba variant: refused, nothing touched."""
    root = _copy(reference, tmp_path)
    if not finished:
        (root / "tiny" / "meta.json").unlink()
    for name in ("render.json", "meta.json"):
        if (root / "tiny" / name).exists():
            _edit_json(root / "tiny" / name, variant="scalar_other")
    before = _snapshot(root)
    _refused(capsys, ["render", str(reference.parent / "tiny.toml"), "--out", str(root), *ARGS],
             str(root / "tiny" / "render.json"), "variant = 'scalar_other'", "--overwrite")
    assert _snapshot(root) == before


def test_captures_of_the_older_noise_streams_are_not_resumed(reference, tmp_path, capsys):
    """An unfinished setup whose record predates the versioned camera noise (no
    ``noise_version``: version 1) would mix two noise streams: refused, nothing touched."""
    root = _copy(reference, tmp_path)
    (root / "tiny" / "meta.json").unlink()
    record = json.loads((root / "tiny" / "render.json").read_text())
    del record["noise_version"]
    (root / "tiny" / "render.json").write_text(json.dumps(record))
    before = _snapshot(root)
    _refused(capsys, ["render", str(reference.parent / "tiny.toml"), "--out", str(root), *ARGS],
             str(root / "tiny" / "render.json"), f"noise_version = 1 (this render: {camera.noise_version()})", "--overwrite")
    assert _snapshot(root) == before


def test_captures_of_a_traced_thin_lens_are_not_resumed_by_the_image_model(tmp_path, capsys):
    """A thin-lens camera's unfinished setup whose record predates ``camera_lens`` (its lens
    traced) would mix two lens models once ``camera.defocus`` defaults to ``"image"``: refused,
    nothing touched; its record names the model."""
    setup = tiny_setup_file(tmp_path, camera={"aperture_radius": 0.01, "focus_distance": 0.6})
    root = tmp_path / "data"
    assert main(["render", str(setup), "--out", str(root), *ARGS]) == 0
    record = json.loads((root / "tiny" / "render.json").read_text())
    assert record["camera_lens"] == "image"
    (root / "tiny" / "meta.json").unlink()
    del record["camera_lens"]
    (root / "tiny" / "render.json").write_text(json.dumps(record))
    before = _snapshot(root)
    _refused(capsys, ["render", str(setup), "--out", str(root), *ARGS],
             str(root / "tiny" / "render.json"), "camera_lens = 'ray' (this render: 'image')", "--overwrite")
    assert _snapshot(root) == before


@pytest.mark.parametrize("option, fragment", [(["--spp", "8"], "spp = 4 (this render: 8)"),
                                              (["--fidelity", "path"], "fidelity = 'direct' (this render: 'path')")])
def test_finished_setup_rendered_otherwise_is_refused(reference, tmp_path, capsys, option, fragment):
    root = _copy(reference, tmp_path)
    before = _snapshot(root)
    _refused(capsys, ["render", str(reference.parent / "tiny.toml"), "--out", str(root), *ARGS, *option],
             fragment)
    assert _snapshot(root) == before


@pytest.mark.slow
def test_overwrite_renders_every_capture_again(reference, tmp_path):
    """--overwrite after a change of setup (or of a record) replaces every capture."""
    fresh = tmp_path / "fresh"
    other = tiny_setup_file(tmp_path / "other", render={"seed": 1})
    assert main(["render", str(other), "--out", str(fresh), *ARGS]) == 0
    root = _copy(reference, tmp_path)
    assert main(["render", str(other), "--out", str(root), *ARGS, "--overwrite"]) == 0
    _assert_same_dataset(root, fresh)
    _edit_json(root / "tiny" / "render.json", variant="scalar_other")
    (root / "tiny" / "meta.json").unlink()
    assert main(["render", str(reference.parent / "tiny.toml"), "--out", str(root), *ARGS, "--overwrite"]) == 0
    _assert_same_dataset(root, reference)


CORRUPT = [("frames.json", "{not json", ["frames.json", "cannot read frames manifest"]),
           ("frames.json", "{}", ["frames.json", "key 'source' = None"]),
           ("frames.json", '{"source": {"width": 32, "height": 32, "seed": 0, "images_dir": null}, '
                           '"counts": 3}', ["frames.json", "key 'counts' = 3"]),
           ("tiny/meta.json", "{oops", ["meta.json", "cannot read"]),
           ("tiny/meta.json", "[]", ["meta.json", "expected a JSON object"]),
           ("tiny/render.json", '{"variant": "llvm_ad_rgb"}', ["render.json", "'width', 'height'"]),
           ("tiny/render.json", '{"variant": 3, "width": 32, "height": 32}', ["render.json", "key 'variant' = 3"])]


@pytest.mark.parametrize("name, content, fragments", CORRUPT)
def test_corrupted_record_is_named(reference, tmp_path, capsys, name, content, fragments):
    root = _copy(reference, tmp_path)
    (root / name).write_text(content)
    before = _snapshot(root)
    _refused(capsys, ["render", str(reference.parent / "tiny.toml"), "--out", str(root), *ARGS], *fragments)
    assert _snapshot(root) == before


def test_meta_counts_of_the_wrong_type_are_named(reference, tmp_path, capsys):
    root = _copy(reference, tmp_path)
    _edit_json(root / "tiny" / "meta.json", counts=5)
    _refused(capsys, ["render", str(reference.parent / "tiny.toml"), "--out", str(root), *ARGS],
             "meta.json: key 'counts' = 5")


# --------------------------------------------------------------------------------- one writer per root

def test_a_root_held_by_another_writer_is_refused(tmp_path, capsys):
    root = tmp_path / "data"
    root.mkdir()
    with open(root / ".lock", "w") as held:
        fcntl.flock(held, fcntl.LOCK_EX)
        _refused(capsys, ["render", str(tiny_setup_file(tmp_path)), "--out", str(root), *ARGS],
                 str(root / ".lock"), "another procam process")
    assert sorted(p.name for p in root.iterdir()) == [".lock"]


@pytest.mark.slow
def test_concurrent_renders_with_other_frame_seeds_one_refused(tmp_path):
    setup = tiny_setup_file(tmp_path)
    procs = [subprocess.Popen([sys.executable, "-m", "compensation.cli", "render", str(setup), "--out",
                               str(tmp_path / "data"), *ARGS, "--frame-seed", str(seed)],
                              env=_env(), stderr=subprocess.PIPE, text=True) for seed in (1, 2)]
    results = [(p.wait(), p.stderr.read()) for p in procs]
    assert sorted(code for code, _ in results) == [0, 2]
    err = next(err for code, err in results if code == 2)
    assert ".lock" in err or "frames.json" in err
    winner = 1 + [code for code, _ in results].index(0)
    assert json.loads((tmp_path / "data" / "frames.json").read_text())["source"]["seed"] == winner
    assert read_png(tmp_path / "data" / "tiny" / "cam" / "warp" / "test" / "img_0001.png").shape == (32, 32, 3)


@pytest.mark.slow
def test_overwrite_repairs_a_damaged_capture_of_a_finished_setup(tmp_path, capsys):
    """A capture damaged after the setup finished is rewritten by --overwrite to its original bytes."""
    from compensation.cli import main as procam

    args = ["render", "ideal", "--out", str(tmp_path / "data"), "--size", "32", "--n-train", "2",
            "--n-test", "1", "--quiet"]
    assert procam(args) == 0
    victim = tmp_path / "data" / "ideal" / "cam" / "warp" / "train" / "img_0001.png"
    good = victim.read_bytes()
    victim.write_bytes(good[:40])
    assert procam(args) == 0 and victim.read_bytes() == good[:40]  # finished: not re-checked
    assert procam([*args, "--overwrite"]) == 0
    assert victim.read_bytes() == good


@pytest.mark.parametrize("projector", [{"brightness": 1e-30},
                                       {"mixing": [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]}])
@pytest.mark.slow
def test_captures_that_do_not_respond_to_the_projector_are_refused(tmp_path, capsys, projector):
    """A projector whose light does not reach the camera gives captures independent of the frame:
    refused with the measured contrast, and the corrected setup renders into the same folder."""
    data = tmp_path / "data"
    _refused(capsys, ["render", str(tiny_setup_file(tmp_path, projector=projector)), "--out", str(data), *ARGS],
             "setup 'tiny': the captures do not respond to the projector", "8-bit levels on average")
    assert not (data / "tiny").exists()  # nothing rendered: no folder left behind
    assert main(["render", str(tiny_setup_file(tmp_path)), "--out", str(data), *ARGS]) == 0
    assert (data / "tiny" / "meta.json").is_file()


@pytest.mark.parametrize("section, key, value, message", [
    ("camera", "resolution", [10 ** 40, 10 ** 40], "camera.resolution = [10000000000000000000000000000000000000000"),
    ("camera", "exposure", 1e-40, "and at least 1.18e-38 in magnitude"),
    ("camera", "read_noise", 1e-40, "and 0 or at least 1.18e-38 in magnitude"),
])
def test_a_number_float32_cannot_hold_is_refused_in_the_terms_of_its_key(tmp_path, capsys, section, key, value,
                                                                          message):
    """An integer key's range speaks for it (not float32); "0 or" only where its range holds 0."""
    setup = tiny_setup_file(tmp_path, **{section: {key: value}})
    err = _refused(capsys, ["render", str(setup), "--out", str(tmp_path / "data"), *ARGS], message)
    assert ("computed in" in err) == (key != "resolution")


def test_a_crash_before_the_first_capture_leaves_nothing_that_blocks_the_rerun(tmp_path, monkeypatch):
    """Not only a refusal: any error before anything is rendered removes the setup file it wrote,
    which used to make the rerun say that the folder holds captures of a different setup."""
    import sim.dataset

    data = tmp_path / "data"

    def crash(*args, **kwargs):
        raise RuntimeError("a crash inside the renderer")

    with monkeypatch.context() as patch:
        patch.setattr(sim.dataset, "_render", crash)
        with pytest.raises(RuntimeError, match="a crash inside the renderer"):
            sim.dataset.write_setup(data, tiny_setup(), FrameSpec(2, 1, (16, 16)), progress=False)
    assert not (data / "tiny").exists()
    brighter = tiny_setup_file(tmp_path, projector={"brightness": 2.0})
    assert main(["render", str(brighter), "--out", str(data), *ARGS]) == 0
    # a folder that holds captures keeps its setup file through a crash, even without the record
    # that folders of older versions lack
    (data / "tiny" / "render.json").unlink()
    with monkeypatch.context() as patch:
        patch.setattr(sim.dataset, "_render", crash)
        with pytest.raises(RuntimeError):
            sim.dataset.write_setup(data, load_setup(brighter), FrameSpec(4, 1, (32, 32)), progress=False)
    assert (data / "tiny" / "setup.toml").is_file() and (data / "tiny" / "cam").is_dir()


def test_ctrl_c_ends_with_a_line_not_a_traceback(tmp_path, capsys, monkeypatch):
    import sim.dataset

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(sim.dataset, "write_setup", interrupted)
    assert main(["render", str(tiny_setup_file(tmp_path)), "--out", str(tmp_path / "data"), *ARGS]) == 130
    err = capsys.readouterr().err
    assert "procam: interrupted" in err and "run the same command again" in err and "Traceback" not in err


def test_ctrl_c_inside_a_mitsuba_render_ends_with_a_line(tmp_path, capsys, monkeypatch):
    import mitsuba as mi

    monkeypatch.setattr(mi, "render", interrupted_render)
    assert main(["render", str(tiny_setup_file(tmp_path)), "--out", str(tmp_path / "data"), *ARGS]) == 130
    err = capsys.readouterr().err
    assert "procam: interrupted" in err and "Traceback" not in err and "RuntimeError" not in err


INTERRUPTER = """
import itertools, os, signal, sys
from pathlib import Path
import sim.io

pattern, nth, argv = sys.argv[1], int(sys.argv[2]), sys.argv[3:]
write, calls = sim.io.atomic_write, itertools.count(1)
# as in a terminal: a runner started in the background of a shell passes SIGINT on ignored
signal.signal(signal.SIGINT, signal.default_int_handler)

def atomic_write(path, data):
    if Path(path).match(pattern) and next(calls) == nth:  # Ctrl-C before writing this file
        os.kill(os.getpid(), signal.SIGINT)
    write(path, data)

sim.io.atomic_write = atomic_write
from compensation.cli import main
sys.exit(main(argv))
"""
"""Run ``procam`` and send it Ctrl-C (SIGINT) as it writes the ``nth`` file matching ``pattern``
(captures are written by worker threads: Python raises it in the main thread, wherever that is,
often inside a render)."""


@pytest.mark.slow
@pytest.mark.parametrize("command", ["render", "study"])
def test_ctrl_c_during_render_and_study_prints_no_traceback(tmp_path, command):
    setup = tiny_setup_file(tmp_path, registration={"method": "exact"})
    (tmp_path / "s.toml").write_text('base = "tiny.toml"\nmethods = ["tps"]\nn_train = 2\nn_test = 1\n'
                                     'size = 16\n[[axis]]\nkey = "ambient.radiance"\nvalues = [0.02, 0.1]\n')
    argv = {"render": ["render", str(setup), "--out", str(tmp_path / "data"), *ARGS],
            "study": ["study", str(tmp_path / "s.toml"), "--out", str(tmp_path / "out"), "--quiet"]}[command]
    proc = subprocess.run([sys.executable, "-c", INTERRUPTER, "*/cam/warp/train/img_*.png", "2", *argv],
                          env=_env(), capture_output=True, text=True)
    assert proc.returncode == 130, proc.stderr
    assert "procam: interrupted" in proc.stderr and "Traceback" not in proc.stderr
    assert not (tmp_path / "out" / "results.csv").exists()  # a study stops: no job is taken for failed


@pytest.mark.parametrize("suite, only, fragment", [
    (["a", "A"], None, 'setup[1].name = "A": expected a unique name (letter case aside)'),
    (["a", "b"], "a,a", "--only a,a: a given twice"),
    (["a", "b"], ",", "--only ',': expected one or more comma-separated setup names"),
    (["a", "b"], "a,,b", "no setup named ''"),
    (["a", "b"], "A", "no setup named 'A'"),
], ids=["names a and A", "--only a,a", "--only ,", "--only a,,b", "--only A"])
def test_suite_names_and_selections_are_checked(tmp_path, capsys, suite, only, fragment):
    tiny_setup_file(tmp_path)
    path = tmp_path / "suite.toml"
    path.write_text('base = "tiny.toml"\n' + "".join(f'[[setup]]\nname = "{n}"\n' for n in suite))
    _refused(capsys, ["render", str(path), "--list", *(["--only", only] if only else [])], fragment)


@pytest.mark.slow
def test_the_fix_a_failed_render_suggests_is_accepted(tmp_path, capsys):
    """A render refused before its first capture (the checkerboard not found at a canonical size too
    small for it) leaves neither its setup record nor frames that block the fixes it suggests: the
    same root takes the corrected setup (the exact map) at another --size, its frames remade with
    no stale frame left. Frames that captures depend on stay protected."""
    data = tmp_path / "data"
    homography = tiny_setup_file(tmp_path, registration={"method": "homography"})
    small = ["--size", "8", "--n-train", "3", "--n-test", "1", "--quiet"]
    _refused(capsys, ["render", str(homography), "--out", str(data), *small],
             "checkerboard corners were not found", "use a larger size")
    assert not (data / "tiny" / "setup.toml").exists()
    exact = tiny_setup_file(tmp_path / "fixed", registration={"method": "exact"})
    other = ["--size", "16", "--n-train", "2", "--n-test", "1", "--quiet"]
    assert main(["render", str(exact), "--out", str(data), *other]) == 0, capsys.readouterr().err
    assert json.loads((data / "frames.json").read_text())["source"]["width"] == 16
    assert sorted(p.name for p in (data / "train").iterdir()) == ["img_0001.png", "img_0002.png"]
    _refused(capsys, ["render", str(exact), "--out", str(data), *small],
             "this root's projector frames were made with")  # now in use: refused


@pytest.mark.slow
def test_a_root_stays_readable_by_the_official_loader(tmp_path, capsys):
    """Every setup of a root keeps as many captures as the root has frames: growing the frames for
    one setup while another is finished with fewer, or capturing fewer than the root's frames, is
    refused before anything is written."""
    data = tmp_path / "data"
    a = tiny_setup_file(tmp_path)
    b = tmp_path / "other.toml"
    b.write_text(tiny_toml("other", 64, texture="checker"))
    assert main(["render", str(a), "--out", str(data), *ARGS]) == 0
    assert main(["render", str(b), "--out", str(data), *ARGS]) == 0
    before = _snapshot(data)
    more = ["--size", "32", "--n-train", "3", "--n-test", "1", "--quiet"]
    _refused(capsys, ["render", str(a), "--out", str(data), *more],
             "would leave other (2 training, 1 test) with fewer captures", "official loader")
    fewer = ["--size", "32", "--n-train", "1", "--n-test", "1", "--quiet"]
    _refused(capsys, ["render", str(a), "--out", str(data), *fewer],
             "this root holds 2 training and 1 test frames", "official loader")
    assert _snapshot(data) == before
