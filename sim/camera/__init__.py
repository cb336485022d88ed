"""The camera outside Mitsuba: optics, sensor, processing and 8-bit encoding of the rendered
linear radiance.

The chain of :func:`capture`, each step skipped (at no cost) when its key is off:

1. optical PSF / anti-alias filter, a Gaussian of ``psf_sigma`` camera pixels
   (:mod:`sim.camera.optics`);
2. radial lens distortion ``distortion`` (Brown's k1), then vignetting ``vignetting``;
3. exposure ``exposure`` (``exposure_mode = "rule"``: set by :func:`rule_exposure`);
4. with ``bayer`` set, the mosaic: one colour channel per pixel (:mod:`sim.camera.raw`);
5. Poisson-Gaussian noise ``shot_noise``, ``read_noise`` (on the mosaic's sites with a Bayer
   sensor; :mod:`sim.camera.noise`), then the full-well clip to [0, 1];
6. white balance ``white_balance``: with a Bayer sensor the digital gain of each site after the
   noise and the clip (clipped to [0, 1] again); without, a per-channel gain ahead of the noise;
7. demosaicing ``demosaic`` (OpenCV) of the mosaic quantised to 16 bits (``vng``: of the mosaic
   encoded to 8 bits by the response curve, OpenCV's VNG being 8-bit only);
8. the response curve ``response`` and 8-bit quantisation (:mod:`sim.camera.response`; computed
   at once from the linear signal by :func:`codes`);
9. JPEG compression and decompression at ``jpeg_quality`` (0: none).

:func:`distort_points` maps ideal pinhole pixel coordinates to where the lens distortion shows
them (for registration). The noise is one Dr.Jit kernel on all cores (:mod:`sim.camera.kernel`;
:func:`noise_version` names the streams); the 8-bit encoder runs block by block, and the noise
where Dr.Jit's LLVM backend is missing on the camera's worker threads (:mod:`sim.camera.threads`).
"""
from sim.camera.noise import BLOCK, expose, noise_sigma, noise_version, sensor_signal
from sim.camera.optics import (apply_optics, blur, distort_image, distort_points,
                               vignetting_profile)
from sim.camera.pipeline import WHITE_CLIPPED_FRACTION, capture, raw_signal, rule_exposure
from sim.camera.raw import (BAYER_PATTERNS, DEMOSAIC_METHODS, channel_map, demosaic, jpeg,
                            mosaic)
from sim.camera.response import (RESPONSE_CURVES, check_response, code_thresholds, codes, decode,
                                 encode, quantisation_sigma, quantise, response_names)

__all__ = [
    "BAYER_PATTERNS", "BLOCK", "DEMOSAIC_METHODS", "RESPONSE_CURVES", "WHITE_CLIPPED_FRACTION",
    "apply_optics", "blur", "capture", "channel_map", "check_response", "code_thresholds", "codes",
    "decode", "demosaic", "distort_image", "distort_points", "encode", "expose", "jpeg", "mosaic",
    "noise_sigma", "noise_version", "quantisation_sigma", "quantise", "raw_signal", "response_names",
    "rule_exposure", "sensor_signal", "vignetting_profile",
]
