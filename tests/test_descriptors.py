"""Physical descriptors of setup keys: the projector's and the camera's defocus blur in canonical
pixels against the thin-lens disk, and the study record and charts that carry them."""
from __future__ import annotations

import json
import math
from dataclasses import replace

import pytest

from compensation.experiments.studies import expand, load_study, study_record
from compensation.reports.charts import tick_labels
from compensation.reports.summary import read_study
from sim.errors import ProcamError
from sim.descriptors import camera_blur, projector_blur
from sim.projector.lens import throw_distance
from sim.projector.scaler import frame_area
from sim.setup import load_setup, scene_path

STUDIES = scene_path("default").parent / "studies"


@pytest.mark.parametrize("aperture", [0.01, 0.04])
@pytest.mark.parametrize("size", [32, 64])
@pytest.mark.slow
def test_projector_blur_is_the_thin_lens_disk_in_canonical_pixels(aperture, size):
    """Head-on plane at distance d, focus f: a disk of A·|d − f|/f metres, over the canonical pixel's
    width on the surface (the panel pixel's width d·2·tan(fov/2)/W times panel pixels per canonical
    pixel)."""
    base = load_setup(scene_path("default"))
    setup = replace(base, projector=replace(base.projector, aperture=aperture, focus_distance=0.8))
    p = setup.projector
    d = throw_distance(setup)
    disk = aperture * abs(d - 0.8) / 0.8
    panel_px = d * 2 * math.tan(math.radians(p.fov) / 2) / p.resolution[0]
    frame_w = frame_area(tuple(p.resolution), (size, size), p.keep_aspect)[2]
    expected = disk / (panel_px * frame_w / size)
    assert projector_blur(setup, (size, size)) == pytest.approx(expected, rel=0.02)
    in_focus = replace(setup, projector=replace(p, focus_distance=d))
    assert projector_blur(in_focus, (size, size)) < 0.05 * expected


def test_camera_blur_is_the_thin_lens_disk_in_canonical_pixels():
    """A camera head-on to a plane at 1 m, focused at 0.6 m: a disk of 2 r |1 - 0.6| / 0.6 metres
    on the surface, over the canonical pixel's width there (the projector's 64-pixel panel 30
    degrees wide at 1 m, seen at 32x32), whatever the camera's resolution and field of view."""
    from helpers import tiny_setup

    want = 2 * 0.01 * 0.4 / 0.6 / (2 * math.tan(math.radians(15)) / 32)
    for resolution, fov in (((64, 64), 40.0), ((200, 120), 45.0)):
        setup = tiny_setup(camera={"position": [0.0, 0.0, 1.0], "resolution": list(resolution), "fov": fov,
                                   "aperture_radius": 0.01, "focus_distance": 0.6})
        assert camera_blur(setup, (32, 32)) == pytest.approx(want, rel=0.02)
    assert camera_blur(tiny_setup(), (32, 32)) == 0.0


@pytest.mark.slow
def test_the_camera_defocus_study_records_its_blur():
    study = load_study(STUDIES / "camera-defocus.toml")
    physical = study_record(study, expand(study))["axes"][0]["physical"]
    assert (physical["label"], physical["unit"]) == ("camera defocus blur", "canonical px")
    # the median over the frame area, foreshortening included (the study file's comment gives the
    # values at the frame area's centre on the surface: 0, 0.28, 0.55, 1.1 and 2.2 px)
    assert physical["values"] == pytest.approx([0.0, 0.29, 0.59, 1.17, 2.34], abs=0.02)


@pytest.mark.slow
def test_a_study_of_the_aperture_records_the_blur_and_its_chart_shows_it():
    study = load_study(STUDIES / "projector-defocus.toml")
    record = study_record(study, expand(study))
    axis = record["axes"][0]
    physical = axis["physical"]
    assert (physical["label"], physical["unit"]) == ("projector defocus blur", "canonical px")
    assert physical["values"][0] == 0.0 and physical["values"] == sorted(physical["values"])
    # twice the aperture, twice the blur (the study file's 0, 0.32, 0.64, 1.3, 2.6 px at 64²)
    assert physical["values"][1:] == pytest.approx([0.32, 0.64, 1.28, 2.56], rel=0.02)
    labels = tick_labels(axis, {v: v for v in axis["values"]})
    assert labels[2] == "0.02\n0.639"
    ambient = study_record(load_study(STUDIES / "ambient.toml"), expand(load_study(STUDIES / "ambient.toml")))
    assert "physical" not in ambient["axes"][0]  # a key without a descriptor records none


@pytest.mark.parametrize("physical", ["blur", {"label": "blur", "unit": "px", "values": [1.0]},
                                      {"label": "blur", "unit": "px", "values": [1.0, "x"]}],
                         ids=["not a table", "one value short", "not a number"])
def test_a_damaged_physical_record_is_named(tmp_path, physical):
    (tmp_path / "study.json").write_text(json.dumps(
        {"axes": [{"key": "projector.aperture", "values": [0.0, 0.01], "physical": physical}]}))
    with pytest.raises(ProcamError, match="axis 'projector.aperture': 'physical' must be"):
        read_study(tmp_path)
