"""Deterministic images: plain colours, projector frames, surface textures and user images.

Nothing is downloaded: photographs are read, once per process, straight from files bundled
in installed wheels (scikit-image's offline ``skimage/data``, matplotlib's sample data, PNG/JPEG
files of at least 256² in the ``colour`` package), never through a loader that may download.
Frames mix seeded crops, flips, hue/saturation/brightness changes of them with procedural
patterns. Values are sRGB-encoded until :func:`srgb_decode` makes surface albedos linear.
"""
from __future__ import annotations

import functools
import importlib.util
import warnings
from pathlib import Path

import cv2
import numpy as np

from sim import seeds
from sim.errors import DatasetError, SetupError
from sim.io import read_png, to_float

PLAIN_LEVELS = (0.0, 0.25, 0.5, 0.75, 1.0)
"""Per-channel levels of the 5³ plain colours (encoded projector input, 0–1)."""
GRAY_LEVEL = 128
"""8-bit level of the plain gray frame x0 that captures the surface image."""
SURFACE_KINDS = ("brick", "grass", "gravel", "photo", "noise", "stripes", "checker", "blobs",
                 "curves", "squares", "lavender", "cloud", "cubes")
"""Names accepted by :func:`surface_texture`."""
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
"""File suffixes (any case) that :func:`load_image_folder` treats as images."""

_PHOTOS = ("astronaut.png", "chelsea.png", "coffee.png", "rocket.jpg", "hubble_deep_field.jpg",
           "ihc.png", "retina.jpg", "color.png", "motorcycle_left.png")
_MAX_SIDE = 1024  # sources are shrunk to this longest side once, at load
_MIN_SIDE = 256  # smaller images in the colour package (icons, logos) are skipped


def srgb_decode(encoded: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 sRGB decoding (EOTF): sRGB-encoded values in [0, 1] -> linear, float32.

    The formula of ``colour.cctf_decoding(x, function="sRGB")``, evaluated in float32. colour
    computes in float64; its result rounded to float32 differs from this one in most values by
    1-4 ulps (relative 3e-7 at most), enough to move about 0.05 % of the 8-bit camera values of a
    rendered dataset by one code. This evaluation is kept so that datasets render byte for byte
    as before.

    Examples
    --------
    >>> [round(float(v), 6) for v in srgb_decode([0.0, 0.5, 1.0])]
    [0.0, 0.214041, 1.0]
    """
    x = np.asarray(encoded, np.float32)
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4).astype(np.float32)


def _wh(size) -> tuple[int, int]:
    """(width, height) in pixels from an int (square) or a (width, height) pair."""
    w, h = (size, size) if np.isscalar(size) else size
    if int(w) < 1 or int(h) < 1:
        raise ValueError(f"image size must be positive (width, height) pixels, got {size!r}")
    return int(w), int(h)


def _resize(img: np.ndarray, w: int, h: int) -> np.ndarray:
    """Resize to (w, h): pixel-area averaging when shrinking, bilinear when enlarging."""
    if img.shape[1] == w and img.shape[0] == h:
        return img
    shrink = w <= img.shape[1] and h <= img.shape[0]
    return cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)


@functools.cache
def _load(path: Path) -> np.ndarray:
    """A bundled image, read-only float32 (H, W, 3) sRGB-encoded in [0, 1], side <= _MAX_SIDE."""
    with warnings.catch_warnings():  # Pillow warns about palette transparency; harmless here
        warnings.simplefilter("ignore", UserWarning)
        img = to_float(read_png(path))
    scale = _MAX_SIDE / max(img.shape[:2])
    if scale < 1:
        img = _resize(img, round(img.shape[1] * scale), round(img.shape[0] * scale))
    img.flags.writeable = False
    return img


def _skimage_file(name: str) -> Path:
    """A file of scikit-image's offline data folder (read directly, no pooch)."""
    import skimage.data

    return Path(skimage.data.__file__).parent / name


@functools.cache
def _photos() -> tuple[np.ndarray, ...]:
    """Every bundled photograph (see the module docstring), loaded once."""
    import matplotlib

    photos = [_load(_skimage_file(n)) for n in _PHOTOS]
    photos.append(_load(Path(matplotlib.get_data_path()) / "sample_data" / "grace_hopper.jpg"))
    spec = importlib.util.find_spec("colour")
    roots = (spec.submodule_search_locations or []) if spec else []
    for path in sorted(p for r in roots for p in Path(r).rglob("*")
                       if p.suffix.lower() in (".png", ".jpg", ".jpeg")):
        try:
            img = _load(path)
        except DatasetError:  # e.g. a gray+alpha icon: not a photograph
            continue
        if min(img.shape[:2]) >= _MIN_SIDE:
            photos.append(img)
    return tuple(photos)


def _colours(rng: np.random.Generator, n: int, sat=(0.4, 1.0), val=(0.35, 1.0)) -> np.ndarray:
    """``n`` random sRGB-encoded colours, float32 (n, 3): uniform hue, sat and value ranges."""
    hsv = np.stack([rng.uniform(0, 360, n), rng.uniform(*sat, n), rng.uniform(*val, n)], -1)
    return cv2.cvtColor(hsv[None].astype(np.float32), cv2.COLOR_HSV2RGB)[0]


def _ramp(t: np.ndarray, colours: np.ndarray) -> np.ndarray:
    """Piecewise-linear colour map of ``t`` in [0, 1] through ``colours`` (n, 3): (H, W, 3)."""
    pos = np.clip(t, 0, 1) * (len(colours) - 1)
    i = np.minimum(pos.astype(np.int32), len(colours) - 2)
    f = (pos - i)[..., None]
    return (colours[i] * (1 - f) + colours[i + 1] * f).astype(np.float32)


@functools.cache
def _grid(w: int, h: int) -> tuple[np.ndarray, np.ndarray]:
    """Pixel-centre coordinates (x, y), float32 (H, W), in units of the shorter side."""
    y, x = np.mgrid[0:h, 0:w].astype(np.float32) + 0.5
    return x / min(w, h), y / min(w, h)


def _axes(rng: np.random.Generator, w: int, h: int) -> tuple[np.ndarray, np.ndarray]:
    """Coordinates (u, v) rotated by a random angle (units of the shorter side)."""
    x, y = _grid(w, h)
    c, s = np.cos(a := rng.uniform(0, np.pi)), np.sin(a)
    return c * x + s * y, c * y - s * x


def _smooth_noise(rng: np.random.Generator, w: int, h: int, channels: int) -> np.ndarray:
    """Low-frequency multi-octave value noise, float32 (H, W, channels), stretched to [0, 1]."""
    acc = np.zeros((h, w, channels), np.float32)
    cells = rng.integers(2, 6)
    for k in range(rng.integers(2, 5)):
        n = cells * 2**k
        grid = rng.random((max(2, n * h // max(w, h)), max(2, n * w // max(w, h)), channels))
        up = cv2.resize(grid.astype(np.float32), (w, h), interpolation=cv2.INTER_CUBIC)
        acc += 0.5**k * up.reshape(h, w, channels)
    lo, hi = acc.min((0, 1)), acc.max((0, 1))
    return (acc - lo) / np.maximum(hi - lo, 1e-6)


def _noise(rng, w, h):
    """Colour noise: each channel blends two random colours with its own noise field."""
    c = _colours(rng, 2)
    return c[0] + (c[1] - c[0]) * _smooth_noise(rng, w, h, 3)


def _stripes(rng, w, h):
    """Stripes at a random angle and period: hard-edged cycling colours or a sine ramp."""
    u = _axes(rng, w, h)[0] / rng.uniform(0.04, 0.3) + rng.random()
    colours = _colours(rng, rng.integers(2, 5))
    if rng.random() < 0.5:
        return colours[np.floor(u).astype(np.int32) % len(colours)]
    return _ramp(0.5 + 0.5 * np.sin(2 * np.pi * u), colours)


def _checker(rng, w, h):
    """A checkerboard of two random colours with a random cell size and rotation."""
    u, v = _axes(rng, w, h)
    cell = rng.uniform(0.05, 0.25)
    return _colours(rng, 2)[(np.floor(u / cell) + np.floor(v / cell)).astype(np.int32) % 2]


def _gradient(rng, w, h):
    """A linear or radial gradient through 2–4 random colours."""
    if rng.random() < 0.5:
        t = _axes(rng, w, h)[0]
    else:
        x, y = _grid(w, h)
        t = np.hypot(x - rng.uniform(0, x.max()), y - rng.uniform(0, y.max()))
    t = (t - t.min()) / max(float(t.max() - t.min()), 1e-6)
    return _ramp(t, _colours(rng, rng.integers(2, 5)))


def _shapes(rng, w, h):
    """Random filled circles, rectangles and polygons in random colours over a gradient."""
    img = np.ascontiguousarray(_gradient(rng, w, h))
    n = rng.integers(5, 40)
    for colour, kind in zip(_colours(rng, n).tolist(), rng.integers(0, 3, n)):
        cx, cy = rng.integers(0, w), rng.integers(0, h)
        r = max(1, round(rng.uniform(0.03, 0.3) * min(w, h)))
        if kind == 0:
            cv2.circle(img, (cx, cy), r, colour, -1, cv2.LINE_AA)
        elif kind == 1:
            dx, dy = rng.integers(1, 2 * r + 1, 2)
            cv2.rectangle(img, (cx - dx, cy - dy), (cx + dx, cy + dy), colour, -1, cv2.LINE_AA)
        else:
            ang = np.sort(rng.uniform(0, 2 * np.pi, rng.integers(3, 8)))
            rad = r * rng.uniform(0.3, 1.0, len(ang))
            pts = np.stack([cx + rad * np.cos(ang), cy + rad * np.sin(ang)], -1).astype(np.int32)
            cv2.fillPoly(img, [pts], colour, cv2.LINE_AA)
    return img


def _blobs(rng, w, h):
    """Soft-edged organic patches: smooth noise cut into 3–5 random colours."""
    t = _smooth_noise(rng, w, h, 1)[..., 0]
    colours = _colours(rng, rng.integers(3, 6))
    img = colours[np.minimum((t * len(colours)).astype(np.int32), len(colours) - 1)]
    return cv2.GaussianBlur(img, (0, 0), max(0.5, 0.004 * min(w, h)))


def _curves(rng, w, h):
    """Wavy bands: stripes along a sinusoidally bent axis, cycling 3–5 colours, soft edges."""
    u, v = _axes(rng, w, h)
    bend = rng.uniform(0.05, 0.2) * np.sin(2 * np.pi * v / rng.uniform(0.3, 1.0) + rng.uniform(0, 6.3))
    t = (u + bend) / rng.uniform(0.06, 0.2)
    colours = _colours(rng, rng.integers(3, 6))
    img = colours[np.floor(t).astype(np.int32) % len(colours)]
    return cv2.GaussianBlur(img, (0, 0), max(0.5, 0.003 * min(w, h)))


def _squares(rng, w, h):
    """A patchwork of axis-aligned squares on a grid, each a random colour, with thin gaps."""
    x, y = _grid(w, h)
    cell = rng.uniform(0.06, 0.2)
    gx, gy = np.floor(x / cell).astype(np.int32), np.floor(y / cell).astype(np.int32)
    colours = _colours(rng, (gx.max() + 1) * (gy.max() + 1))
    img = colours[gy * (gx.max() + 1) + gx]
    gap = rng.uniform(0.05, 0.15)
    edge = (np.mod(x / cell, 1) < gap) | (np.mod(y / cell, 1) < gap)
    img[edge] = _colours(rng, 1, sat=(0.0, 0.2), val=(0.8, 1.0))[0]
    return img


def _lavender(rng, w, h):
    """A floral print: dense small purple florets over green and brown, at two scales."""
    purple = np.array([[0.55, 0.45, 0.8], [0.4, 0.3, 0.65], [0.7, 0.6, 0.9]], np.float32)
    ground = np.array([[0.35, 0.45, 0.25], [0.45, 0.4, 0.3]], np.float32)
    t = _smooth_noise(rng, w, h, 1)[..., 0]
    img = _ramp(t, ground)
    fine = cv2.resize(rng.random((max(2, h // 6), max(2, w // 6))).astype(np.float32), (w, h),
                      interpolation=cv2.INTER_CUBIC)
    shade = _ramp(cv2.resize(rng.random((max(2, h // 3), max(2, w // 3))).astype(np.float32), (w, h)),
                  purple)
    img = np.where(((fine > 0.55) & (t > 0.25))[..., None], shade, img)
    return cv2.GaussianBlur(img, (0, 0), 0.7)


def _cloud(rng, w, h):
    """A sky print: soft white clouds over a blue gradient (low contrast, low frequency)."""
    sky = _ramp(_grid(w, h)[1] / max(h / min(w, h), 1e-6),
                np.array([[0.35, 0.55, 0.85], [0.6, 0.75, 0.95]], np.float32))
    cloud = np.clip(_smooth_noise(rng, w, h, 1) * 1.6 - 0.5, 0, 1)
    return sky * (1 - cloud) + cloud * np.float32(0.97)


def _cubes(rng, w, h):
    """Isometric cubes: a tiling of hexagons split into three rhombi shaded light, mid and dark."""
    x, y = _grid(w, h)
    side = rng.uniform(0.05, 0.15)
    # Axial hexagon coordinates of each pixel (pointy-top hexagons of circumradius ``side``).
    q = (np.sqrt(3) / 3 * x - y / 3) / side
    r = (2 / 3 * y) / side
    cx, cz = q, r
    cy = -cx - cz
    rx, ry, rz = np.round(cx), np.round(cy), np.round(cz)
    dx, dy, dz = np.abs(rx - cx), np.abs(ry - cy), np.abs(rz - cz)
    fix_x = (dx > dy) & (dx > dz)
    fix_y = ~fix_x & (dy > dz)
    rx = np.where(fix_x, -ry - rz, rx)
    ry = np.where(fix_y, -rx - rz, ry)
    rz = np.where(~fix_x & ~fix_y, -rx - ry, rz)
    # Which third of the hexagon: the angle of the pixel around its hexagon's centre.
    hx = side * np.sqrt(3) * (rx + rz / 2)
    hy = side * 1.5 * rz
    face = (np.floor((np.arctan2(y - hy, x - hx) + np.pi / 2) / (2 * np.pi / 3)).astype(np.int32)) % 3
    colours = _colours(rng, 4)
    tile = (rx.astype(np.int32) * 7 + rz.astype(np.int32) * 13) % len(colours)
    shade = np.array([1.0, 0.75, 0.5], np.float32)[face]
    return colours[tile] * shade[..., None]


def _photo(rng: np.random.Generator, w: int, h: int) -> np.ndarray:
    """A random photograph's random crop of aspect w:h (30–100 % of the largest one), randomly
    flipped, resized to (w, h)."""
    src = _photos()[rng.integers(len(_photos()))]
    sh, sw = src.shape[:2]
    cw = max(1, min(sw, round(min(sw, sh * w / h) * rng.uniform(0.3, 1.0))))
    ch = max(1, min(sh, round(cw * h / w)))
    x0, y0 = rng.integers(0, sw - cw + 1), rng.integers(0, sh - ch + 1)
    out = _resize(src[y0:y0 + ch, x0:x0 + cw], w, h)
    flip = rng.integers(0, 4)  # 0 vertical, 1 horizontal, 2 both, 3 none
    return cv2.flip(out, (0, 1, -1)[flip]) if flip < 3 else out


_PATTERNS = (_noise, _stripes, _checker, _gradient, _shapes)
FRAME_KINDS = ("mixed", "photo")
"""Kinds of generated projector frames (:func:`projector_frames`)."""


def _frame(seed: int, stream: int, index: int, w: int, h: int, kind: str = "mixed") -> np.ndarray:
    """Projector frame ``index`` of (seed, stream) of a kind of :data:`FRAME_KINDS`: uint8
    (H, W, 3), sRGB-encoded."""
    if kind == "photo":  # its own generator: a mixed frame of the same index is unchanged
        rng = np.random.default_rng([seeds.FRAME_TAG, seed, stream, index, FRAME_KINDS.index(kind)])
        return np.clip(_photo(rng, w, h) * 255 + 0.5, 0, 255).astype(np.uint8)
    rng = np.random.default_rng([seeds.FRAME_TAG, seed, stream, index])
    choice = rng.random()  # 45 % photographs, 30 % patterns, 25 % blends of both
    if choice < 0.45:
        img = _photo(rng, w, h)
    elif choice < 0.75:
        img = _PATTERNS[rng.integers(len(_PATTERNS))](rng, w, h)
    else:
        a, pattern = rng.uniform(0.3, 0.7), _PATTERNS[rng.integers(len(_PATTERNS))](rng, w, h)
        img = a * _photo(rng, w, h) + (1 - a) * pattern
    hsv = cv2.cvtColor(np.clip(img * 255 + 0.5, 0, 255).astype(np.uint8), cv2.COLOR_RGB2HSV)
    levels = np.arange(256, dtype=np.float64)
    hue = (levels + (rng.integers(180) if rng.random() < 0.8 else 0)) % 180  # OpenCV hue: 0–179
    sat = levels * rng.uniform(1.0, 1.6)
    val = 255 * (levels / 255) ** np.exp(rng.uniform(-0.4, 0.4))
    lut = np.clip(np.stack([hue, sat, val], -1) + 0.5, 0, 255).astype(np.uint8)[None]
    return cv2.cvtColor(cv2.LUT(hsv, lut), cv2.COLOR_HSV2RGB)


def plain_colours() -> np.ndarray:
    """The 5³ plain colours of ``ref/img_0001.png … img_0125.png``, in file order.

    Returns
    -------
    numpy.ndarray
        ``uint8`` (125, 3), sRGB-encoded 8-bit values ``round(255 * level)`` of
        :data:`PLAIN_LEVELS`; row ``25 r + 5 g + b`` holds level indices (r, g, b), blue
        fastest: row 0 is black, row 124 white.
    """
    levels = np.rint(255 * np.asarray(PLAIN_LEVELS)).astype(np.uint8)
    r, g, b = np.meshgrid(levels, levels, levels, indexing="ij")
    return np.stack([r, g, b], -1).reshape(-1, 3)


def plain_frame(rgb_uint8, size) -> np.ndarray:
    """A uniform projector frame of the 8-bit sRGB-encoded colour ``rgb_uint8`` (3,).

    ``size`` is a side or (width, height) in pixels; returns ``uint8`` (H, W, 3).
    """
    w, h = _wh(size)
    return np.broadcast_to(np.asarray(rgb_uint8, np.uint8).reshape(3), (h, w, 3)).copy()


def projector_frames(count: int, size, seed: int, stream: int = 0, kind: str = "mixed") -> np.ndarray:
    """``count`` colourful, textured, mutually different projector frames.

    Frame ``i`` depends only on (seed, stream, i, kind), so a longer run starts with a shorter
    run's frames; a dataset's training and test frames use the streams
    :data:`sim.seeds.TRAIN_FRAMES` and :data:`sim.seeds.TEST_FRAMES` (non-negative integers).

    Parameters
    ----------
    size : int or (int, int)
        Side, or (width, height), in pixels.
    kind : str
        One of :data:`FRAME_KINDS`: ``"mixed"``, crops of the bundled photographs (45 %),
        procedural patterns (30 %) and blends of both (25 %), each with a random hue rotation,
        saturation boost and gamma; ``"photo"``, crops of the bundled photographs with their own
        colours (natural images, as in the paper's datasets).

    Returns
    -------
    numpy.ndarray
        ``uint8`` (count, H, W, 3), sRGB-encoded projector input.

    Raises
    ------
    ValueError
        If ``kind`` is not one of :data:`FRAME_KINDS`.
    """
    if kind not in FRAME_KINDS:
        raise ValueError(f"projector frames of kind {kind!r}: expected one of {', '.join(FRAME_KINDS)}")
    w, h = _wh(size)
    out = np.empty((count, h, w, 3), np.uint8)
    for i in range(count):
        out[i] = _frame(seed, stream, i, w, h, kind)
    return out


def surface_texture(kind: str, resolution, seed: int) -> np.ndarray:
    """A surface albedo texture; each non-negative ``seed`` gives another crop, pattern, colour.

    Parameters
    ----------
    kind : str
        One of :data:`SURFACE_KINDS`: ``brick``/``grass``/``gravel`` are scikit-image's gray
        textures, mirror-tiled and cropped at their own pixel scale, tinted a seeded colour;
        ``photo`` is a crop of a bundled photograph; the others are coloured patterns.
    resolution : (int, int)
        (width, height) in pixels.

    Returns
    -------
    numpy.ndarray
        float32 (H, W, 3) LINEAR albedo in [0, 1] (sRGB-decoded), row 0 at the top.

    Raises
    ------
    ValueError
        If ``kind`` is unknown (the message lists :data:`SURFACE_KINDS`).
    """
    if kind not in SURFACE_KINDS:
        raise ValueError(f"unknown surface texture kind {kind!r}; expected one of "
                         f"{', '.join(SURFACE_KINDS)}")
    w, h = _wh(resolution)
    rng = np.random.default_rng([seeds.SURFACE_TAG, seed, SURFACE_KINDS.index(kind)])
    if kind in ("brick", "grass", "gravel"):
        gray = _load(_skimage_file(f"{kind}.png"))[..., 0]
        gray = np.pad(gray, ((0, max(0, h - gray.shape[0])), (0, max(0, w - gray.shape[1]))),
                      mode="symmetric")
        y0, x0 = rng.integers(0, gray.shape[0] - h + 1), rng.integers(0, gray.shape[1] - w + 1)
        gray = np.minimum(gray[y0:y0 + h, x0:x0 + w] / np.percentile(gray, 99.5), 1)
        encoded = gray[..., None] * _colours(rng, 1, sat=(0.2, 0.7), val=(0.7, 1.0))[0]
    elif kind == "photo":
        encoded = _photo(rng, w, h)
    else:
        encoded = {"noise": _noise, "stripes": _stripes, "checker": _checker, "blobs": _blobs,
                   "curves": _curves, "squares": _squares, "lavender": _lavender, "cloud": _cloud,
                   "cubes": _cubes}[kind](rng, w, h)
    return np.clip(srgb_decode(encoded), 0, 1)


def load_texture_file(path, resolution) -> np.ndarray:
    """A user's sRGB-encoded 8-bit image file (PNG, JPEG, …) as float32 (H, W, 3) LINEAR albedo
    in [0, 1], resized (pixel-area averaging, not cropped) to ``resolution`` (width, height) px.

    Raises
    ------
    SetupError
        If the file is missing or cannot be read (the message names the path).
    """
    try:
        img = read_png(path)
    except DatasetError as exc:
        raise SetupError(f"surface texture: {exc}") from None
    w, h = _wh(resolution)
    img = cv2.resize(to_float(img), (w, h), interpolation=cv2.INTER_AREA)
    return np.clip(srgb_decode(img), 0, 1)


def load_image_folder(folder, count: int, size) -> np.ndarray:
    """The user's own projector frames, as they are: the first ``count`` image files of
    ``folder`` (suffixes :data:`IMAGE_SUFFIXES`, any case) sorted by name.

    Each is resized to ``size`` (a side or (width, height), pixels) by pixel-area averaging when
    shrinking and bilinearly when enlarging, never cropped or recoloured; gray becomes RGB and
    alpha is dropped. Returns ``uint8`` (count, H, W, 3), sRGB-encoded as stored.

    Raises
    ------
    DatasetError
        If the folder is missing, holds fewer than ``count`` images, or one cannot be read.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise DatasetError(f"{folder}: image folder not found")
    files = sorted((p for p in folder.iterdir()
                    if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES), key=lambda p: p.name)
    if len(files) < count:
        raise DatasetError(f"{folder}: found {len(files)} image files "
                           f"({', '.join(IMAGE_SUFFIXES)}), need {count}")
    w, h = _wh(size)
    out = np.empty((count, h, w, 3), np.uint8)
    for i, path in enumerate(files[:count]):
        out[i] = _resize(read_png(path), w, h)
    return out
