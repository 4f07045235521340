"""Analytic ray casting of a :class:`Scene` into a :class:`Camera`: image, exact depth, silhouette."""
from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np

from workers.camera import Camera

from .scene import Scene, Sphere


@dataclass(frozen=True)
class SynthView:
    """One rendered view.

    image: (H, W, 3) uint8 BGR. depth: (H, W) float32, z along the optical axis in metres, inf where
    the ray hits nothing. silhouette: (H, W) bool, pixel centre sees a foreground object.
    background: (H, W, 3) uint8 BGR, the same view with the foreground removed (None when not asked).
    object_id: (H, W) int16, index into ``scene.objects`` of the visible primitive, -1 for sky.
    """

    camera: Camera
    image: np.ndarray
    depth: np.ndarray
    silhouette: np.ndarray
    background: np.ndarray | None
    object_id: np.ndarray


def render(
    scene: Scene, camera: Camera, *, supersample: int = 1, gain: tuple[float, float, float] | float = 1.0,
    with_background: bool = True,
) -> SynthView:
    """Ray-cast ``scene`` as seen by ``camera``, through its lens distortion when it has one (each pixel's
    ray is its undistorted direction, so the image is exactly what the distorted camera sees).

    supersample: s > 1 averages s x s rays per pixel for the images (anti-aliasing); depth,
    silhouette and ids always come from the pixel-centre ray. gain: per-channel (B, G, R) or scalar
    factor on the final colour, to mimic cameras with different exposure/white balance.
    """
    depth, ids, color = _cast(scene, camera, 1)
    if supersample == 1:
        image = _to_uint8(color, gain)
    else:
        image = _shade_image(scene, camera, supersample, gain)
    background = None
    if with_background:
        background = _shade_image(scene.background_only(), camera, supersample, gain)
    fg = np.array([o.foreground for o in scene.objects] + [False])
    silhouette = fg[ids]  # id -1 indexes the trailing False
    return SynthView(camera, image, depth.astype(np.float32), silhouette, background, ids.astype(np.int16))


def _shade_image(scene: Scene, camera: Camera, s: int, gain: tuple[float, float, float] | float) -> np.ndarray:
    _, _, color = _cast(scene, camera, s)
    return _to_uint8(color.reshape(camera.height, s, camera.width, s, 3).mean(axis=(1, 3)), gain)


def _to_uint8(color: np.ndarray, gain: tuple[float, float, float] | float) -> np.ndarray:
    return np.clip(np.rint(color * np.asarray(gain, np.float64)), 0, 255).astype(np.uint8)


def _ray_dirs(camera: Camera, s: int) -> np.ndarray:
    """Directions (H*s*W*s, 3) whose camera-z component is 1, for s x s sub-pixel rays, row-major."""
    offs = (np.arange(s) + 0.5) / s - 0.5
    u = (np.arange(camera.width)[:, None] + offs[None, :]).ravel()
    v = (np.arange(camera.height)[:, None] + offs[None, :]).ravel()
    if camera.has_distortion:
        xn = _undistorted_rays(camera.K.tobytes(), camera.dist.tobytes(), camera.width, camera.height, s)
        R = camera.R  # (xn, 1) @ R, written out: no BLAS thread start-up
        return xn[:, 0:1] * R[0] + xn[:, 1:2] * R[1] + R[2]
    M = camera.R.T @ np.linalg.inv(camera.K)
    D = np.empty((v.size, u.size, 3))
    D[:] = M[:, 2]
    D += u[None, :, None] * M[:, 0]  # broadcasting instead of a BLAS matmul: no thread start-up
    D += v[:, None, None] * M[:, 1]
    return D.reshape(-1, 3)


@functools.lru_cache(maxsize=2)
def _undistorted_rays(K: bytes, dist: bytes, width: int, height: int, s: int) -> np.ndarray:
    """Normalised undistorted directions (N, 2) of a distorted camera's s x s sub-pixel rays (the lens model
    inverted per ray, iterated well past OpenCV's default 5 steps); the last two kept (a frame's pixel-centre rays
    and its sub-pixel rays), for the frames of a flight (one camera, many poses)."""
    offs = (np.arange(s) + 0.5) / s - 0.5
    u = (np.arange(width)[:, None] + offs[None, :]).ravel()
    v = (np.arange(height)[:, None] + offs[None, :]).ravel()
    uv = np.stack(np.meshgrid(u, v), axis=-1).reshape(-1, 1, 2)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    K3 = np.frombuffer(K, np.float64).reshape(3, 3)
    xn = cv2.undistortPointsIter(uv, K3, np.frombuffer(dist, np.float64), None, None, crit).reshape(-1, 2)
    xn.setflags(write=False)
    return xn


def _cast(scene: Scene, camera: Camera, s: int,
          rays: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Depth (H*s, W*s), object ids and shaded colours (H*s, W*s, 3) float64 for s x s sub-rays; with
    ``rays`` (N,) flat indices of some of them: depth (N,), ids (N,) and colours (N, 3) of those alone
    (each ray's result does not depend on the others)."""
    o = camera.center
    D = _ray_dirs(camera, s)
    if rays is not None:
        D = np.ascontiguousarray(D[rays])
    n = len(D)
    best_t = np.full(n, np.inf)
    ids = np.full(n, -1, np.int64)
    normals = np.zeros((n, 3))
    for k, obj in enumerate(scene.objects):
        obj.intersect_into(o, D, k, best_t, ids, normals)
    color = np.empty((n, 3))
    color[:] = scene.sky
    light = np.asarray(scene.light_dir, np.float64)
    light /= np.linalg.norm(light)
    for k, obj in enumerate(scene.objects):
        sel = np.flatnonzero(ids == k)
        if sel.size == 0:
            continue
        X = o + best_t[sel, None] * D[sel]
        nrm = normals[sel] / np.linalg.norm(normals[sel], axis=1, keepdims=True)
        tex = obj.material.texture.sample(obj.local(X)).astype(np.float64)
        share = _lit_share(scene, X, nrm) if scene.shadows > 0 else 1.0
        lam = np.maximum(nrm @ light, 0.0) * share if scene.shadows > 0 else np.abs(nrm @ light)
        c = tex * (scene.ambient + scene.diffuse * lam)[:, None]
        if obj.material.specular > 0:
            c += 255.0 * obj.material.specular * (share * _phong(nrm, light, D[sel], obj.material.shininess))[:, None]
        color[sel] = c
    if rays is not None:
        return best_t, ids, color
    h, w = camera.height * s, camera.width * s
    return best_t.reshape(h, w), ids.reshape(h, w), color.reshape(h, w, 3)


def _lit_share(scene: Scene, X: np.ndarray, nrm: np.ndarray) -> np.ndarray:
    """Share (N,) of the light's shadow rays from points X (N, 3) with unit normals (N, 3) that no
    sphere or box blocks (0 for points facing away from a ray)."""
    occluders = [o for o in scene.objects if getattr(o, "casts_shadow", False)]
    dirs = scene.shadow_directions()
    facing = np.flatnonzero((nrm @ dirs.T).max(axis=1) > 0)  # the others are dark whatever stands in the way
    O = np.ascontiguousarray(X[facing] + 1e-5 * nrm[facing])
    lit = np.zeros(len(X))
    for d in dirs:
        blocked = (nrm[facing] @ d <= 0).astype(np.uint8)
        for o in occluders:
            o.blocks_into(O, np.ascontiguousarray(d), blocked)
        lit[facing] += 1 - blocked
    return lit / len(dirs)


def _phong(nrm: np.ndarray, light: np.ndarray, D: np.ndarray, shininess: float) -> np.ndarray:
    """Phong highlight (N,) for unit normals (N, 3), light (3,) and view rays D (N, 3)."""
    view = -D / np.linalg.norm(D, axis=1, keepdims=True)
    nrm = np.where((nrm @ light)[:, None] < 0, -nrm, nrm)  # light the side facing the light
    refl = 2 * (nrm @ light)[:, None] * nrm - light
    return np.clip(np.einsum("ij,ij->i", refl, view), 0, 1) ** shininess


def render_moved(scene: Scene, still: SynthView, sphere: Sphere, margin: float = 0.01) -> np.ndarray:
    """``render(scene, camera).image`` (supersample 1, gain 1) from ``still``, the view (by :func:`render`,
    same camera) of ``scene`` without ``sphere``, a sphere of ``scene``: only the pixels the sphere can
    change are cast again: rays that pass within ``margin`` m of it, and (with shadows) surface points of
    ``still`` whose ray towards the light's disc passes within ``margin`` m of it. Equal to the full
    render pixel for pixel (each ray is cast alone); (H, W, 3) uint8 BGR."""
    cam = still.camera
    D = _ray_dirs(cam, 1)
    c = np.asarray(sphere.center, np.float64) - cam.center
    r = float(sphere.radius) + margin
    t = (D @ c) / np.einsum("ij,ij->i", D, D)
    hit = np.linalg.norm(c[None, :] - np.maximum(t, 0)[:, None] * D, axis=1) < r  # the ray passes within r
    if scene.shadows > 0:
        depth = still.depth.ravel().astype(np.float64)
        ok = np.isfinite(depth)
        X = cam.center + depth[ok, None] * D[ok]
        light = np.asarray(scene.light_dir, np.float64)
        light /= np.linalg.norm(light)
        v = np.asarray(sphere.center, np.float64) - X
        along = v @ light
        perp = np.linalg.norm(v - along[:, None] * light, axis=1)
        reach = np.linalg.norm(v, axis=1) * np.sin(min(1.01 * scene.light_spread, np.pi / 2))  # the disc's rays
        shade = (along > -r) & (perp < r + reach)
        hit[np.flatnonzero(ok)[shade]] = True
    rays = np.flatnonzero(hit)
    image = still.image.copy()
    if rays.size:
        _, _, color = _cast(scene, cam, 1, rays)
        image.reshape(-1, 3)[rays] = _to_uint8(color, 1.0)
    return image


def render_views(
    scene: Scene, cameras: list[Camera], *, supersample: int = 1,
    gains: list[tuple[float, float, float] | float] | None = None, with_background: bool = True,
) -> list[SynthView]:
    """:func:`render` for each camera; ``gains`` (one per camera) default to 1."""
    gains = gains if gains is not None else [1.0] * len(cameras)
    if len(gains) != len(cameras):
        raise ValueError(f"gains: {len(gains)} given for {len(cameras)} cameras")
    return [render(scene, c, supersample=supersample, gain=g, with_background=with_background)
            for c, g in zip(cameras, gains)]
