"""Surface statistics: how bright, saturated and contrasted the captured surface images are.

The surface image of a dataset (``cam/warp/ref/img_0126.png``: the surface under the plain gray
frame, warped to the canonical view) is summarised by exposure-sensitive and exposure-free
statistics; the same statistics of external surface images (e.g. crops of published figures of a
real rig's surface captures, given as ``FILE:x0,y0,x1,y1``) are printed beside them::

    .venv/bin/python benchmarks/surfaces.py DATA_ROOT [--image NAME=FILE:x0,y0,x1,y1 ...]

Statistics, of the 8-bit encoded image: ``mean`` (all channels), the 5th and 95th percentiles of
Rec. 709 luma, mean HSV saturation, and luma's relative standard deviation (std / mean).
"""
from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import imageio.v3 as iio
import numpy as np

from sim import layout


def stats(image: np.ndarray) -> dict[str, float]:
    """Statistics of a uint8 (H, W, 3) encoded image (see the module docstring).

    Examples
    --------
    >>> s = stats(np.full((4, 4, 3), 128, np.uint8))
    >>> round(s["mean"], 3), round(s["saturation"], 3), round(s["rel_std"], 3)
    (0.502, 0.0, 0.0)
    """
    x = image.astype(np.float64) / 255
    luma = x @ np.array([0.2126, 0.7152, 0.0722])
    sat = cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2HSV)[..., 1] / 255
    return {"mean": float(x.mean()), "luma_p5": float(np.percentile(luma, 5)),
            "luma_p95": float(np.percentile(luma, 95)), "saturation": float(sat.mean()),
            "rel_std": float(luma.std() / max(luma.mean(), 1e-12))}


def _crop(spec: str) -> tuple[str, np.ndarray]:
    name, rest = spec.split("=", 1)
    path, box = rest.rsplit(":", 1)
    x0, y0, x1, y1 = (int(v) for v in box.split(","))
    return name, np.ascontiguousarray(iio.imread(path)[y0:y1, x0:x1, :3])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("data", type=Path, help="dataset root (one folder per setup)")
    ap.add_argument("--image", action="append", default=[], metavar="NAME=FILE:x0,y0,x1,y1",
                    help="an external surface image to compare with (a crop of FILE)")
    args = ap.parse_args()
    rows = [_crop(spec) for spec in args.image]
    surface = Path(layout.CAM, layout.WARP, layout.REF, layout.image_name(layout.SURFACE_NUMBER))
    for folder in sorted(p for p in args.data.iterdir() if (p / surface).is_file()):
        rows.append((folder.name, iio.imread(folder / surface)[..., :3]))
    print("| surface image | mean | luma p5 | luma p95 | saturation | luma std / mean |")
    print("|---|---|---|---|---|---|")
    for name, image in rows:
        s = stats(image)
        print(f"| {name} | {s['mean']:.3f} | {s['luma_p5']:.3f} | {s['luma_p95']:.3f} | "
              f"{s['saturation']:.3f} | {s['rel_std']:.3f} |")


if __name__ == "__main__":
    main()
