"""The no-text set: images with nothing to read, on which the orientation text cue must decide nothing (issue 33).

Built on this machine from what is installed (``apt-get install gnome-backgrounds mate-backgrounds
mypaint-data-extras``; scikit-image comes with the bench extra; a source that is missing is left out and the section
says how many images each category had), never committed (each source's licence allows local benchmark use):

- ``dev noup``: ``$SWEEPCAST_DATA/orientation/noup`` (textures, microscopy, aerial views; see its PROVENANCE);
- ``aerial``: ``$SWEEPCAST_DATA/sfm/drone_fc350/images``, nadir stills of a cheap drone (fields, roads, roofs);
- ``wallpapers``: Debian's ``gnome-backgrounds`` (CC-BY-SA 3.0) and ``mate-backgrounds`` abstract and desktop images
  (GPL-2+ / CC-BY-SA), leaving out those with a logo, icons or words;
- ``foliage``: ``mate-backgrounds`` nature photos (leaves, grass, flowers, sky);
- ``fabric/paper``: ``mypaint-data-extras`` paper and canvas textures (GPL-2+);
- ``skimage``: scikit-image's bundled photos that ``dev noup`` does not already hold (CC0 / public domain);
- ``leptonica``: the photos and scans with nothing to read among Leptonica's test images
  (:mod:`benchmarks._leptonica`, fetched from Debian's archive on first use);
- ``generated``: textures made here with fixed seeds: field patchworks seen from above with crop rows and wind
  turbines (the satellite photo that fooled the old text cue), woven fabric, foliage, crowds of heads seen from
  above, stripes, cells, fractal noise.

:func:`no_text_images` lists (category, name, loader) for each; a loaded image is BGR, its long side at most
``MAX_SIDE``.
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable

import cv2
import numpy as np

from benchmarks._leptonica import NO_TEXT as LEPTONICA_NO_TEXT, images as leptonica_images

MAX_SIDE = 2000
"""Long side (px) the installed images are reduced to (the text cue reads at most 2400 px; decoding 20 MP
wallpapers four times over costs more than it tells)."""
DEBIAN_PACKAGES = ("gnome-backgrounds", "mate-backgrounds", "mypaint-data-extras")
_WALLPAPERS = ("/usr/share/backgrounds/gnome", "/usr/share/backgrounds/mate/abstract", "/usr/share/backgrounds/mate/desktop")
_LEFT_OUT = {"pixels-d.webp", "pixels-l.webp",  # icons
             "Float-into-MATE.png", "GreenTraditional.jpg",  # the MATE logo and its name
             "MATE-Stripes-Dark.png", "MATE-Stripes-Light.png",  # the same, in their alpha (blank without it)
             "Arc-Colors-Transparent-Wallpaper.png",  # an alpha mask, white when flattened
             "Elephants_3840x2160.jpg", "Elephants_5640x3172.jpg"}  # the same picture as Elephants.jpg
_SKIMAGE = ("retina.jpg", "microaneurysms.png", "coffee.png", "chelsea.png", "camera.png", "horse.png")
_SUFFIXES = (".jpg", ".jpeg", ".png", ".webp", ".JPG")


def _load(path: Path) -> np.ndarray | None:
    image = _flattened(cv2.imread(str(path), cv2.IMREAD_UNCHANGED))
    if image is None:
        return None
    s = MAX_SIDE / max(image.shape[:2])
    return cv2.resize(image, None, fx=s, fy=s, interpolation=cv2.INTER_AREA) if s < 1 else image


def _flattened(image: np.ndarray | None) -> np.ndarray | None:
    """BGR uint8 of an image read as stored (grey, 16-bit, alpha): a wallpaper with an alpha channel drawn over mid
    grey, as a desktop shows it over its colour (MATE's Silk, Spring, Waves and Stripes are a white or black layer
    whose picture is all in its alpha: without it they were blank pages, four identical photos of nothing in the
    library)."""
    if image is None:
        return None
    if image.dtype == np.uint16:
        image = (image >> 8).astype(np.uint8)
    if image.ndim == 2:
        return cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    if image.shape[2] == 4:
        alpha = image[..., 3:].astype(np.float32) / 255.0
        return np.round(image[..., :3].astype(np.float32) * alpha + 128.0 * (1.0 - alpha)).astype(np.uint8)
    return image


def _files(folder: Path | None, names: tuple[str, ...] | None = None) -> list[Path]:
    if folder is None or not folder.is_dir():
        return []
    found = sorted(p for p in folder.iterdir() if p.suffix in _SUFFIXES and p.name not in _LEFT_OUT)
    return [p for p in found if names is None or p.name in names]


def sources(data_root: Path) -> dict[str, list[Path]]:
    """The installed and shared images per category (paths), in a fixed order."""
    try:
        import skimage
        skimage_data = Path(skimage.__file__).parent / "data"
    except ImportError:  # the bench extra brings it
        skimage_data = None
    wallpapers = [p for folder in _WALLPAPERS for p in _files(Path(folder))]
    mypaint = Path("/usr/share/mypaint/backgrounds")
    return {
        "dev noup": _files(data_root / "orientation" / "noup"),
        "aerial": _files(data_root / "sfm" / "drone_fc350" / "images"),
        "wallpapers": wallpapers,
        "foliage": _files(Path("/usr/share/backgrounds/mate/nature")),
        "fabric/paper": [p for sub in sorted(mypaint.glob("*")) for p in _files(sub)] if mypaint.is_dir() else [],
        "skimage": _files(skimage_data, _SKIMAGE),
        "leptonica": [lept / name for name in LEPTONICA_NO_TEXT] if (lept := leptonica_images()) else [],
    }


# ---- generated textures (fixed seeds) ------------------------------------------------------------------------------

def _noise(rng: np.random.Generator, shape: tuple[int, int], octaves: int = 5) -> np.ndarray:
    """Fractal value noise in [0, 1] (float32, ``shape``)."""
    h, w = shape
    out = np.zeros(shape, np.float32)
    for o in range(octaves):
        cells = 2 ** (o + 2)
        grid = rng.random((cells + 1, cells + 1)).astype(np.float32)
        out += cv2.resize(grid, (w, h), interpolation=cv2.INTER_CUBIC) / 2 ** o
    out -= out.min()
    return out / max(float(out.max()), 1e-6)


def fields(rng: np.random.Generator, size: tuple[int, int] = (1365, 2048)) -> np.ndarray:
    """A nadir view of farmland: fields of different crops (shades, crop rows at each field's angle), roads between
    them and wind turbines (a mast's shadow and three blades)."""
    h, w = size
    image = np.zeros((h, w, 3), np.uint8)
    xs = np.sort(rng.integers(0, w, 5)); ys = np.sort(rng.integers(0, h, 4))
    xs = np.concatenate([[0], xs, [w]]); ys = np.concatenate([[0], ys, [h]])
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    for i in range(len(ys) - 1):
        for j in range(len(xs) - 1):
            base = rng.integers(60, 200, 3)
            angle = rng.uniform(0, np.pi)
            period = rng.uniform(6, 22)
            rows = 0.5 + 0.5 * np.sin((xx * np.cos(angle) + yy * np.sin(angle)) * 2 * np.pi / period)
            cell = (slice(ys[i], ys[i + 1]), slice(xs[j], xs[j + 1]))
            shade = base[None, None, :] * (0.75 + 0.35 * rows[cell][..., None])
            image[cell] = np.clip(shade, 0, 255).astype(np.uint8)
    for x in xs[1:-1]:
        cv2.line(image, (int(x), 0), (int(x + rng.integers(-80, 80)), h), (170, 170, 170), int(rng.integers(4, 12)))
    for y in ys[1:-1]:
        cv2.line(image, (0, int(y)), (w, int(y + rng.integers(-60, 60))), (150, 150, 150), int(rng.integers(4, 12)))
    for _ in range(int(rng.integers(3, 8))):
        cx, cy, r = int(rng.integers(100, w - 100)), int(rng.integers(100, h - 100)), int(rng.integers(30, 70))
        cv2.line(image, (cx, cy), (cx + 2 * r, cy + r), (40, 40, 40), 3)  # the mast's shadow
        for k in range(3):
            a = rng.uniform(0, 2 * np.pi) + k * 2 * np.pi / 3
            cv2.line(image, (cx, cy), (int(cx + r * np.cos(a)), int(cy + r * np.sin(a))), (245, 245, 245), 4)
        cv2.circle(image, (cx, cy), 5, (230, 230, 230), -1)
    grain = (_noise(rng, (h, w)) * 40 - 20)[..., None]
    return np.clip(image.astype(np.float32) + grain, 0, 255).astype(np.uint8)


def weave(rng: np.random.Generator, size: tuple[int, int] = (1200, 1600)) -> np.ndarray:
    """Woven fabric: warp and weft threads over and under, two colours, a little irregularity."""
    h, w = size
    period = int(rng.integers(8, 20))
    yy, xx = np.mgrid[0:h, 0:w]
    over = ((xx // period) + (yy // period)) % 2 == 0
    warp = 0.5 + 0.5 * np.cos(2 * np.pi * (xx % period) / period)
    weft = 0.5 + 0.5 * np.cos(2 * np.pi * (yy % period) / period)
    a, b = rng.integers(30, 230, 3), rng.integers(30, 230, 3)
    image = np.where(over[..., None], a * (0.6 + 0.4 * weft[..., None]), b * (0.6 + 0.4 * warp[..., None]))
    image += (_noise(rng, (h, w)) * 50 - 25)[..., None]
    return np.clip(image, 0, 255).astype(np.uint8)


def foliage(rng: np.random.Generator, size: tuple[int, int] = (1200, 1600)) -> np.ndarray:
    """Leaves: overlapping green ellipses with a midrib, darker below."""
    h, w = size
    image = np.full((h, w, 3), (20, 60, 25), np.uint8)
    for _ in range(900):
        cx, cy = int(rng.integers(0, w)), int(rng.integers(0, h))
        a, b = int(rng.integers(15, 60)), int(rng.integers(6, 25))
        angle = float(rng.uniform(0, 180))
        color = tuple(int(v) for v in (rng.integers(10, 70), rng.integers(90, 200), rng.integers(20, 90)))
        cv2.ellipse(image, (cx, cy), (a, b), angle, 0, 360, color, -1, cv2.LINE_AA)
        t = np.deg2rad(angle)
        cv2.line(image, (int(cx - a * np.cos(t)), int(cy - a * np.sin(t))),
                 (int(cx + a * np.cos(t)), int(cy + a * np.sin(t))), tuple(min(255, c + 40) for c in color), 1)
    return image


def crowd(rng: np.random.Generator, size: tuple[int, int] = (1200, 1600)) -> np.ndarray:
    """A crowd seen from above: heads (dark, fair, hats) over shoulders in clothes of every colour."""
    h, w = size
    image = np.full((h, w, 3), 90, np.uint8)
    for _ in range(700):
        cx, cy = int(rng.integers(0, w)), int(rng.integers(0, h))
        cloth = tuple(int(v) for v in rng.integers(0, 256, 3))
        cv2.ellipse(image, (cx, cy), (int(rng.integers(22, 32)), int(rng.integers(12, 18))),
                    float(rng.uniform(0, 180)), 0, 360, cloth, -1, cv2.LINE_AA)
        hair = tuple(int(v) for v in (rng.integers(10, 90),) * 3) if rng.random() < 0.8 else cloth
        cv2.circle(image, (cx + int(rng.integers(-4, 5)), cy + int(rng.integers(-4, 5))), int(rng.integers(9, 13)),
                   hair, -1, cv2.LINE_AA)
    return cv2.GaussianBlur(image, (0, 0), 1.0)


def stripes(rng: np.random.Generator, size: tuple[int, int] = (1200, 1600)) -> np.ndarray:
    """Bands of several widths at one angle, with noise (blinds, corrugated roofs, ploughed soil)."""
    h, w = size
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    angle = rng.uniform(0, np.pi)
    u = xx * np.cos(angle) + yy * np.sin(angle)
    value = sum(np.sin(u * 2 * np.pi / p + rng.uniform(0, 6)) for p in rng.uniform(8, 80, 3))
    image = 128 + 40 * value + 30 * (_noise(rng, (h, w)) - 0.5)
    return cv2.cvtColor(np.clip(image, 0, 255).astype(np.uint8), cv2.COLOR_GRAY2BGR)


def cells(rng: np.random.Generator, size: tuple[int, int] = (1200, 1600)) -> np.ndarray:
    """Voronoi cells with dark walls (cobblestones, cracked mud, tissue)."""
    h, w = size
    points = rng.random((260, 2)) * (w, h)
    subdiv = cv2.Subdiv2D((0, 0, w, h))
    for p in points:
        subdiv.insert((float(p[0]), float(p[1])))
    facets, _ = subdiv.getVoronoiFacetList([])
    image = np.zeros((h, w, 3), np.uint8)
    for facet in facets:
        shade = int(rng.integers(90, 220))
        cv2.fillConvexPoly(image, facet.astype(np.int32), (shade, shade - 10, shade - 25))
        cv2.polylines(image, [facet.astype(np.int32)], True, (30, 30, 30), 3)
    return image


def fractal(rng: np.random.Generator, size: tuple[int, int] = (1200, 1600)) -> np.ndarray:
    """Coloured fractal noise (clouds, marble, rock)."""
    h, w = size
    return np.stack([(_noise(rng, (h, w)) * 255).astype(np.uint8) for _ in range(3)], axis=-1)


GENERATORS = {"fields": fields, "weave": weave, "foliage": foliage, "crowd": crowd, "stripes": stripes,
              "cells": cells, "fractal": fractal}
GENERATED_PER_KIND = 4


def no_text_images(data_root: Path, every: int = 1) -> list[tuple[str, str, Callable[[], np.ndarray]]]:
    """(category, name, load the BGR image) of the whole set (every ``every``-th image of each category, for
    subsets); an image is read or generated only when it is loaded."""
    out: list[tuple[str, str, Callable[[], np.ndarray]]] = []
    for category, paths in sources(data_root).items():
        out += [(category, p.name, lambda p=p: _load(p)) for p in paths[::every]]
    kinds = [(f"{kind}-{seed}", make, seed) for kind, make in GENERATORS.items() for seed in range(GENERATED_PER_KIND)]
    out += [("generated", name, lambda make=make, seed=seed: make(np.random.default_rng(1000 + seed)))
            for name, make, seed in kinds[::every]]
    return out


def describe(data_root: Path) -> dict[str, int]:
    """How many images each category has here (the generated ones always)."""
    counts = {k: len(v) for k, v in sources(data_root).items()}
    counts["generated"] = len(GENERATORS) * GENERATED_PER_KIND
    return counts
