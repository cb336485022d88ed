"""The camera outside Mitsuba: optics, sensor, processing and 8-bit encoding of the rendered
linear radiance.

:func:`capture` is the whole camera: the chain of :data:`~sim.camera.chain.CHAIN` in order
(optical PSF, veiling glare (:mod:`~sim.camera.glare`), lens distortion, vignetting
(:mod:`~sim.camera.optics`); the sensor
(:mod:`~sim.camera.sensor`): exposure, Bayer mosaic, Poisson-Gaussian noise and the full-well
clip, white balance, demosaicing, response curve, the processing of the encoded image (adaptive
tone, :mod:`~sim.camera.adaptive`; picture style and sharpening, :mod:`~sim.camera.style`) and
8-bit quantisation; JPEG), each stage skipped (at no cost) when its keys switch it off;
:func:`without_optics`, :func:`sensor_alone` and :func:`noise_version` follow from the stages'
flags (:mod:`sim.camera.chain`). Each stage's
module declares its keys, which make up :class:`sim.setup.CameraConfig`.

:func:`distort_points` maps ideal pinhole pixel coordinates to where the lens distortion shows
them (for registration). The noise is one Dr.Jit kernel on all cores (:mod:`sim.camera.kernel`;
:func:`~sim.camera.noise.stream_version` names the streams); the 8-bit encoder runs block by
block, and the noise where Dr.Jit's LLVM backend is missing on the camera's worker threads
(:mod:`sim.camera.threads`).
"""
from sim.camera.chain import CHAIN, STAGES, noise_version, sensor_alone, without_optics
from sim.camera.noise import BLOCK, expose, noise_sigma, sensor_signal
from sim.camera.optics import blur, distort_image, distort_points, vignetting_profile
from sim.camera.pipeline import WHITE_CLIPPED_FRACTION, apply_optics, capture, rule_exposure
from sim.camera.raw import (BAYER_PATTERNS, DEMOSAIC_METHODS, channel_map, demosaic, jpeg,
                            mosaic)
from sim.camera.response import (RESPONSE_NAMES, check_response, code_thresholds, codes, decode,
                                 encode, quantisation_sigma, quantise, response_names)
from sim.camera.sensor import raw_signal

__all__ = [
    "BAYER_PATTERNS", "BLOCK", "CHAIN", "DEMOSAIC_METHODS", "RESPONSE_NAMES", "STAGES",
    "WHITE_CLIPPED_FRACTION",
    "apply_optics", "blur", "capture", "channel_map", "check_response", "code_thresholds", "codes",
    "decode", "demosaic", "distort_image", "distort_points", "encode", "expose", "jpeg", "mosaic",
    "noise_sigma", "noise_version", "quantisation_sigma", "quantise", "raw_signal", "response_names",
    "rule_exposure", "sensor_alone", "sensor_signal", "vignetting_profile", "without_optics",
]
