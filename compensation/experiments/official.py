"""The official CompenNet code's outputs of a run, in its layout::

    cam/cmp/<tag>/img_XXXX.png    π†(x̃) for the test captures x̃ (what the surrogate metrics score)
    prj/cmp/<tag>/img_XXXX.png    π†(y) for the test images y: the frames to project

with the tag of :func:`official_tag` (e.g. ``CompenNet_l1+ssim_500_64_1000``).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from compensation.data import N_PLAIN, SetupData
from compensation.methods import get_method
from compensation.training.config import TrainConfig
from compensation.experiments.runs import load_run
from sim.errors import ProcamError
from sim.io import write_png
from sim.layout import image_name


def official_tag(cfg: TrainConfig, pretrained: bool = False) -> str:
    """The official code's name of a run's output folder: ``<model>_<loss>_<ntrain>_<batch>_<iters>``.

    ``<model>`` is the method's ``official_name`` (``_pretrained`` appended for a pre-trained
    initialisation); ``<ntrain>`` the training pairs it fits (125 for a method that fits the plain
    colours whatever ``n_train``); a method without a ``loss``, ``batch`` or ``iters`` option leaves
    that field out (pix2pix: ``pix2pix_125_1_10000``); options that name themselves in the tag
    (:meth:`~compensation.training.config.Options.tag`: a spline's smoothing) come last.

    Examples
    --------
    >>> from compensation.methods import make_config
    >>> official_tag(make_config("paper", "compennet"))
    'CompenNet_l1+ssim_500_64_1000'
    >>> official_tag(make_config("quick", "tps-textured", n_train=250))
    'TPS_textured_250_lambda0.003'
    >>> official_tag(make_config("paper", "tps", n_train=250))
    'TPS_125_lambda0.0347alpha2'
    """
    options, method = cfg.options, get_method(cfg.method)
    model = method.official_name + ("_pretrained" if pretrained else "")
    n_train = N_PLAIN if method.plain_colours else cfg.n_train
    fields = [model] + ([options.loss] if hasattr(options, "loss") else []) + [str(n_train)]
    fields += [str(getattr(options, k)) for k in ("batch", "iters") if hasattr(options, k)]
    return "_".join(fields + ([options.tag()] if options.tag() else []))


def official_uint8(image: np.ndarray) -> np.ndarray:
    """8-bit values as the official code writes its outputs: ``np.uint8(x * 255)`` of float32
    images in [0, 1], i.e. truncated, not rounded (values outside [0, 1], which no method
    predicts, are clipped first).

    >>> official_uint8(np.array([0.0, 0.5, 0.999, 1.0], np.float32)).tolist()
    [0, 127, 254, 255]
    """
    return (np.clip(np.asarray(image, np.float32), 0, 1) * np.float32(255)).astype(np.uint8)


def write_official_outputs(run_dir: Path, data: SetupData, dest: Path, tag: str,
                           cam: torch.Tensor | None = None) -> None:
    """Write a run's π†(x̃) of the test captures to ``dest/cam/cmp/<tag>`` and its π†(y) of the
    test images y (the test frames) to ``dest/prj/cmp/<tag>``, as ``img_XXXX.png`` with the
    official code's 8-bit values (:func:`official_uint8`), so the files are byte for byte those the
    official code would write from the same predictions.

    ``cam``, when given, is the run's π†(x̃) of ``data``'s test captures as the run predicted them
    (:func:`~compensation.experiments.runs.train_run` returns it), written instead of predicting
    them again."""
    method, config = load_run(run_dir)
    batch = config["train"].get("eval_batch", 64)
    if cam is not None and cam.shape != data.test.captures.shape:
        raise ProcamError(f"{run_dir}: {tuple(cam.shape)} predictions given for "
                          f"{tuple(data.test.captures.shape)} test captures")
    for kind, inputs in (("cam", data.test.captures), ("prj", data.test.frames)):
        predicted = cam if kind == "cam" and cam is not None else method.predict(inputs, data.surface,
                                                                                   batch_size=batch)
        frames = predicted.permute(0, 2, 3, 1).numpy()
        for i, frame in enumerate(frames, start=1):
            write_png(dest / kind / "cmp" / tag / image_name(i), official_uint8(frame))


def official_complete(dest: Path, tag: str, n: int) -> bool:
    """Whether ``dest`` holds ``n`` images of both kinds under ``tag``."""
    return all(len(list((dest / kind / "cmp" / tag).glob("img_*.png"))) == n for kind in ("cam", "prj"))
