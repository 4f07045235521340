"""View synthesis by depth-image-based rendering (DIBR), used to judge depth maps.

Pipeline per source view: forward-warp its depth to the target camera with a z-buffer (nearest
wins), fill one-pixel cracks of the warped depth with the farther neighbour, then sample the
source texture backwards through the warped depth (bilinear). A sample is kept only when the
source pixel it reads has the depth the warp expects (occluded samples become holes), and the
``boundary_width`` pixels on the background side of each disocclusion are dropped: they hold the
mixed foreground/background colours of the object boundary that would otherwise leave a ghost
outline in the background (VSRS's "boundary noise removal"). Several warped views are blended:
at each pixel the nearest surface wins and views that see that same surface are averaged with
weights (nearer cameras weigh more). Remaining holes (disocclusions no view saw) are filled from
the background side along the row.

Geometry: "rectified" views differ by a horizontal camera shift; a source pixel at x with disparity
d (pixels for a reference baseline) lands at ``x - shift * d`` where ``shift`` is the target's camera
x minus the source's, in reference baselines (Middlebury: disparity d of im2 maps im2 to im6, so
the reference baseline is 4 view spacings and im2 -> im4 has shift 0.5). "General" views are
:class:`workers.camera.Camera` (K, world-to-camera R, t) with depth Z in metres.

Nearness: rectified warps carry disparity (pixels per reference baseline), general warps 1/Z
(1/metres) of the target camera; both grow towards the camera, and the views being blended must
use the same kind.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import cv2
import numba
import numpy as np

from workers.camera import Camera

from .errors import DepthInputError

HOLE_FILLS = ("background", "inpaint", "none")


@dataclass(frozen=True)
class WarpedView:
    """One source view warped to the target: ``image`` (H, W, 3) uint8 BGR (0 where not valid),
    ``valid`` (H, W) bool, ``nearness`` (H, W) float32 (-inf where not valid)."""

    image: np.ndarray
    valid: np.ndarray
    nearness: np.ndarray


@dataclass(frozen=True)
class Synthesis:
    """A synthesised view: ``image`` (H, W, 3) uint8 BGR with holes filled as asked, and
    ``holes`` (H, W) bool, the pixels no source view saw."""

    image: np.ndarray
    holes: np.ndarray


def check_texture_depth(texture: np.ndarray, depth: np.ndarray, what: str = "depth") -> None:
    """Raise DepthInputError unless texture is (H, W, 3) uint8 and depth is (H, W) of the same size."""
    if texture.dtype != np.uint8 or texture.ndim != 3 or texture.shape[2] != 3:
        raise DepthInputError(f"texture must be an 8-bit colour image (H, W, 3), got {texture.dtype} {texture.shape}")
    if depth.ndim != 2:
        raise DepthInputError(f"{what} must be a single-channel (H, W) map, got shape {depth.shape}")
    if texture.shape[:2] != depth.shape:
        raise DepthInputError(
            f"texture is {texture.shape[1]}x{texture.shape[0]} but {what} is {depth.shape[1]}x{depth.shape[0]}: "
            "they must be the same size"
        )


def warp_rectified(
    texture: np.ndarray, disparity: np.ndarray, shift: float, crack_fill: bool = True,
    depth_tolerance: float = 0.05, boundary_width: int = 1,
) -> WarpedView:
    """Warp one rectified view horizontally by ``shift`` reference baselines.

    texture: (H, W, 3) uint8 BGR. disparity: (H, W) float32 pixels for the reference baseline,
    NaN where unknown (such pixels are not warped). Target x = x - shift * d, same row.
    depth_tolerance: relative disparity mismatch above which a backward sample counts as occluded
    (mismatches that move the point by at most half a pixel are always accepted).
    boundary_width: pixels dropped on the background side of each disocclusion (0 keeps them).
    """
    disparity = np.asarray(disparity, np.float32)
    check_texture_depth(texture, disparity, "disparity")
    h, w = disparity.shape
    xs = np.arange(w, dtype=np.float32)[None, :]
    ys = np.repeat(np.arange(h, dtype=np.float32)[:, None], w, axis=1)
    near = _splat(xs - np.float32(shift) * disparity, ys, disparity, h, w)
    if crack_fill:
        near = _fill_cracks(near, False)
    map_x = np.where(np.isfinite(near), xs + np.float32(shift) * near, 0).astype(np.float32)
    # also accept disparity errors that move the point by at most half a pixel (slanted surfaces)
    slack = 0.5 / max(abs(float(shift)), 1e-6)
    return _sample_back(texture, disparity, map_x, ys, near, near, depth_tolerance, boundary_width, slack)


def warp_general(
    texture: np.ndarray, depth_m: np.ndarray, source: Camera, target: Camera, crack_fill: bool = True,
    depth_tolerance: float = 0.05, boundary_width: int = 1,
) -> WarpedView:
    """Warp one view with depth to another pinhole camera.

    texture: (H, W, 3) uint8 BGR; depth_m: (H, W) float32 depth Z in metres along the source's
    optical axis, NaN/inf/<= 0 where unknown. source/target: cameras without distortion; the source
    size must equal the texture size. Output has the target's size; nearness is 1/Z_target.
    depth_tolerance, boundary_width: as in :func:`warp_rectified` (disocclusions are found along rows).
    """
    depth_m = np.asarray(depth_m, np.float32)
    check_texture_depth(texture, depth_m)
    for cam in (source, target):
        if cam.has_distortion:
            raise DepthInputError(f"camera {cam.name!r} has lens distortion: undistort the images first")
    if (source.width, source.height) != (depth_m.shape[1], depth_m.shape[0]):
        raise DepthInputError(
            f"camera {source.name!r} is {source.width}x{source.height} but its depth map is "
            f"{depth_m.shape[1]}x{depth_m.shape[0]}"
        )
    h, w = depth_m.shape
    z = np.where(np.isfinite(depth_m) & (depth_m > 0), depth_m, np.nan)
    X_t = _transfer(source, target, _pixel_rays(source, w, h), z)
    with np.errstate(divide="ignore", invalid="ignore"):
        u, v, inv_z = X_t[..., 0] / X_t[..., 2], X_t[..., 1] / X_t[..., 2], 1.0 / X_t[..., 2]
    inv_z = np.where(X_t[..., 2] > 0, inv_z, np.nan).astype(np.float32)
    uv = _apply_K(target.K, u, v)
    near = _splat(uv[0].astype(np.float32), uv[1].astype(np.float32), inv_z, target.height, target.width)
    if crack_fill:
        near = _fill_cracks(near, True)
    with np.errstate(divide="ignore", invalid="ignore"):
        z_t = np.where(near > 0, 1.0 / near, np.nan)
    X_s = _transfer(target, source, _pixel_rays(target, target.width, target.height), z_t)
    with np.errstate(divide="ignore", invalid="ignore"):
        us, vs = X_s[..., 0] / X_s[..., 2], X_s[..., 1] / X_s[..., 2]
        expected = (1.0 / X_s[..., 2]).astype(np.float32)
    uv_s = _apply_K(source.K, us, vs)
    ok = np.isfinite(uv_s[0]) & np.isfinite(uv_s[1])
    map_x = np.where(ok, uv_s[0], 0).astype(np.float32)
    map_y = np.where(ok, uv_s[1], 0).astype(np.float32)
    with np.errstate(divide="ignore"):
        src_near = (1.0 / z).astype(np.float32)
    return _sample_back(texture, src_near, map_x, map_y, near, expected, depth_tolerance, boundary_width, 0.0)


def warp_disparity(disparity: np.ndarray, shift: float, crack_fill: bool = True) -> np.ndarray:
    """Forward-warp a rectified disparity map by ``shift`` reference baselines (z-buffered).

    disparity: (H, W) float32 pixels, NaN where unknown. Returns (H, W) float32 disparity seen from
    the target camera, NaN where nothing lands (disocclusions, outside the source's view).
    """
    disparity = np.asarray(disparity, np.float32)
    if disparity.ndim != 2:
        raise DepthInputError(f"disparity must be (H, W), got shape {disparity.shape}")
    h, w = disparity.shape
    xs = np.arange(w, dtype=np.float32)[None, :]
    ys = np.repeat(np.arange(h, dtype=np.float32)[:, None], w, axis=1)
    near = _splat(xs - np.float32(shift) * disparity, ys, disparity, h, w)
    if crack_fill:
        near = _fill_cracks(near, False)
    return np.where(np.isfinite(near), near, np.nan).astype(np.float32)


def fill_depth_holes(nearness: np.ndarray) -> np.ndarray:
    """Fill unknown (NaN) pixels of a nearness map (disparity or 1/Z) (H, W) from the background
    side along each row, then along columns for empty rows; returns (H, W) float32."""
    near = np.asarray(nearness, np.float32)
    valid = np.isfinite(near)
    if valid.all() or not valid.any():
        return near.copy()
    view = WarpedView(near[..., None].copy(), valid, np.where(valid, near, -np.inf).astype(np.float32))
    return fill_holes(view)[..., 0]


def blend(views: Sequence[WarpedView], weights: Sequence[float] | None = None, depth_tolerance: float = 0.05) -> WarpedView:
    """Blend warped views of one target: nearest surface wins; views within ``depth_tolerance``
    (relative nearness) of it are averaged with ``weights`` (default equal)."""
    if not views:
        raise DepthInputError("need at least one source view")
    shape = views[0].valid.shape
    if any(v.valid.shape != shape for v in views):
        raise DepthInputError("all warped views must have the same size")
    weights = [1.0] * len(views) if weights is None else list(weights)
    near = np.max(np.stack([v.nearness for v in views]), axis=0)
    acc = np.zeros(shape + (3,), np.float32)
    wsum = np.zeros(shape, np.float32)
    for view, wt in zip(views, weights):
        use = view.valid & (view.nearness >= near - depth_tolerance * np.abs(near))
        wmap = use.astype(np.float32) * np.float32(wt)
        acc += view.image.astype(np.float32) * wmap[..., None]
        wsum += wmap
    valid = wsum > 0
    image = np.zeros(shape + (3,), np.uint8)
    image[valid] = np.clip(acc[valid] / wsum[valid][:, None] + 0.5, 0, 255).astype(np.uint8)
    return WarpedView(image, valid, np.where(valid, near, -np.inf).astype(np.float32))


def fill_holes(view: WarpedView, method: str = "background") -> np.ndarray:
    """Fill the pixels of ``view`` that are not valid; returns (H, W, 3) uint8.

    "background": each horizontal hole run copies the end pixel with the smaller nearness (the
    background side of a disocclusion), then columns for rows with nothing valid; "inpaint":
    OpenCV Telea inpainting; "none": holes stay black.
    """
    if method not in HOLE_FILLS:
        raise DepthInputError(f"unknown hole filling {method!r}; expected one of {', '.join(HOLE_FILLS)}")
    if method == "none" or view.valid.all():
        return view.image
    if method == "inpaint":
        return cv2.inpaint(view.image, (~view.valid).astype(np.uint8), 3, cv2.INPAINT_TELEA)
    image, valid = _fill_rows(view.image.copy(), view.valid.copy(), view.nearness)
    if not valid.all():
        image_t, _ = _fill_rows(
            np.ascontiguousarray(image.transpose(1, 0, 2)), np.ascontiguousarray(valid.T),
            np.ascontiguousarray(view.nearness.T),
        )
        image = np.ascontiguousarray(image_t.transpose(1, 0, 2))
    return image


def synthesize(
    views: Sequence[WarpedView], weights: Sequence[float] | None = None, hole_fill: str = "background",
    depth_tolerance: float = 0.05,
) -> Synthesis:
    """Blend warped views and fill the holes; ``holes`` marks pixels no view saw."""
    merged = blend(views, weights, depth_tolerance)
    return Synthesis(fill_holes(merged, hole_fill), ~merged.valid)


def synthesize_rectified(
    textures: Sequence[np.ndarray], disparities: Sequence[np.ndarray], shifts: Sequence[float],
    hole_fill: str = "background", depth_tolerance: float = 0.05, boundary_width: int = 1,
) -> Synthesis:
    """Synthesise a rectified target from views at ``shifts`` (target x - source x, in reference
    baselines); each view weighs 1/|shift|. Arrays and options as in :func:`warp_rectified`."""
    if not (len(textures) == len(disparities) == len(shifts)) or not textures:
        raise DepthInputError("give the same number (at least one) of textures, depth maps and camera positions")
    warped = [
        warp_rectified(t, d, s, depth_tolerance=depth_tolerance, boundary_width=boundary_width)
        for t, d, s in zip(textures, disparities, shifts)
    ]
    weights = [1.0 / max(abs(s), 1e-6) for s in shifts]
    return synthesize(warped, weights, hole_fill, depth_tolerance)


def synthesize_general(
    textures: Sequence[np.ndarray], depths_m: Sequence[np.ndarray], cameras: Sequence[Camera], target: Camera,
    hole_fill: str = "background", depth_tolerance: float = 0.05, boundary_width: int = 1,
) -> Synthesis:
    """Synthesise ``target`` from calibrated views; each weighs 1 / (distance between camera centres).
    Arrays and options as in :func:`warp_general`."""
    if not (len(textures) == len(depths_m) == len(cameras)) or not textures:
        raise DepthInputError("give the same number (at least one) of textures, depth maps and cameras")
    warped = [
        warp_general(t, d, c, target, depth_tolerance=depth_tolerance, boundary_width=boundary_width)
        for t, d, c in zip(textures, depths_m, cameras)
    ]
    weights = [1.0 / max(float(np.linalg.norm(c.center - target.center)), 1e-9) for c in cameras]
    return synthesize(warped, weights, hole_fill, depth_tolerance)


def _pixel_rays(cam: Camera, w: int, h: int) -> np.ndarray:
    """Normalised camera-frame rays (h, w, 3) float64 with z = 1 for every pixel centre."""
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    pix = np.stack([u, v, np.ones_like(u)], axis=-1)
    return pix @ np.linalg.inv(cam.K).T


def _transfer(a: Camera, b: Camera, rays_a: np.ndarray, z_a: np.ndarray) -> np.ndarray:
    """Points at depth z_a (h, w) along rays of camera a -> camera-b frame coordinates (h, w, 3)."""
    X_a = rays_a * z_a[..., None]
    R = b.R @ a.R.T  # camera a frame -> camera b frame
    return X_a @ R.T + (b.t - R @ a.t)


def _apply_K(K: np.ndarray, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return K[0, 0] * u + K[0, 1] * v + K[0, 2], K[1, 1] * v + K[1, 2]


def _sample_back(
    texture: np.ndarray, src_near: np.ndarray, map_x: np.ndarray, map_y: np.ndarray, near: np.ndarray,
    expected: np.ndarray, tol: float, boundary_width: int, slack: float,
) -> WarpedView:
    """Sample the source texture at (map_x, map_y) where ``near`` is set, keeping only samples whose
    source pixel has the expected nearness (within ``tol`` relative plus ``slack`` absolute) and that
    are not within ``boundary_width`` of a disocclusion on its background side."""
    h, w = texture.shape[:2]
    image = cv2.remap(texture, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    xi = np.clip(np.rint(map_x), 0, w - 1).astype(np.intp)
    yi = np.clip(np.rint(map_y), 0, h - 1).astype(np.intp)
    seen = src_near[yi, xi]
    inside = (map_x > -0.5) & (map_x < w - 0.5) & (map_y > -0.5) & (map_y < h - 0.5)
    with np.errstate(invalid="ignore"):
        valid = (
            np.isfinite(near) & np.isfinite(expected) & inside
            & (np.abs(seen - expected) <= tol * np.abs(expected) + slack + 1e-6)
        )
    if boundary_width > 0:
        valid = _drop_background_boundaries(valid, np.where(valid, near, -np.inf).astype(np.float32), boundary_width)
    image[~valid] = 0
    return WarpedView(image, valid, np.where(valid, near, -np.inf).astype(np.float32))


@numba.njit(cache=True)
def _splat(xt, yt, key, h, w):
    """Z-buffered point splat: target (h, w) float32 holding the largest key landing on each pixel."""
    buf = np.full((h, w), -np.inf, np.float32)
    rows, cols = key.shape
    for i in range(rows):
        for j in range(cols):
            k = key[i, j]
            x, y = xt[i, j], yt[i, j]
            if not (np.isfinite(k) and np.isfinite(x) and np.isfinite(y)):
                continue
            xi = int(np.floor(x + 0.5))
            yi = int(np.floor(y + 0.5))
            if 0 <= xi < w and 0 <= yi < h and k > buf[yi, xi]:
                buf[yi, xi] = k
    return buf


@numba.njit(cache=True)
def _fill_cracks(buf, vertical):
    """Fill empty pixels whose two horizontal (and, if asked, vertical) neighbours are set, with
    the farther of them: cracks open where a surface is stretched by the warp."""
    h, w = buf.shape
    out = buf.copy()
    for y in range(h):
        for x in range(w):
            if np.isfinite(buf[y, x]):
                continue
            best = np.inf
            if 0 < x < w - 1 and np.isfinite(buf[y, x - 1]) and np.isfinite(buf[y, x + 1]):
                best = min(buf[y, x - 1], buf[y, x + 1])
            if vertical and 0 < y < h - 1 and np.isfinite(buf[y - 1, x]) and np.isfinite(buf[y + 1, x]):
                best = min(best, min(buf[y - 1, x], buf[y + 1, x]))
            if best < np.inf:
                out[y, x] = best
    return out


@numba.njit(cache=True)
def _drop_background_boundaries(valid, near, width):
    """Invalidate ``width`` pixels at the background end of every interior hole run of each row."""
    h, w = valid.shape
    out = valid.copy()
    for y in range(h):
        x = 0
        while x < w:
            if valid[y, x]:
                x += 1
                continue
            start = x
            while x < w and not valid[y, x]:
                x += 1
            left, right = start - 1, x
            if left < 0 or right >= w:
                continue
            if near[y, left] < near[y, right]:
                for k in range(max(0, left - width + 1), left + 1):
                    out[y, k] = False
            else:
                for k in range(right, min(w, right + width)):
                    out[y, k] = False
    return out


@numba.njit(cache=True)
def _fill_rows(image, valid, near):
    """Fill each run of invalid pixels in a row from its background (smaller nearness) end."""
    h, w = valid.shape
    for y in range(h):
        x = 0
        while x < w:
            if valid[y, x]:
                x += 1
                continue
            a = x
            while x < w and not valid[y, x]:
                x += 1
            left, right = a - 1, x
            if left < 0 and right >= w:
                continue
            if left < 0:
                src = right
            elif right >= w:
                src = left
            else:
                src = left if near[y, left] <= near[y, right] else right
            for xx in range(a, x):
                image[y, xx] = image[y, src]
                valid[y, xx] = True
    return image, valid
