"""Procedural scenes with exact ground truth, by analytic ray casting (numpy + a numba noise kernel).

Stable API (import from ``workers.synth``; world frame z up, metres; colours BGR 0..255; cameras
are :class:`workers.camera.Camera`, see that module for conventions):

Scene description
- ``Scene(objects, light_dir=..., ambient=0.45, diffuse=0.55, sky=(b, g, r))``; ``scene.background_only()``.
- Primitives, each with ``material=Material(texture, specular=0.0, shininess=40.0)`` and
  ``foreground`` (True: part of the silhouette; False: static background):
  ``Sphere(center, radius, ...)``, ``Box(center, size, ..., yaw_deg=0.0)`` (size = full edge
  lengths, turned about z), ``Plane(point=(0,0,0), normal=(0,0,1), ...)`` (infinite; default
  foreground=False).
- Solid 3D textures (evaluated at the surface point, so every camera sees the same colour):
  ``Solid(color)``, ``Checker(color_a, color_b, size)``, ``Noise(color_a, color_b, scale, octaves, seed)``,
  ``ColorNoise(scale, octaves, seed, mean, contrast)``; ``fractal_noise(P, scale, octaves, seed)``.
  From photographs (BGR float images): ``Picture(image, size, u_axis, v_axis)`` (projected),
  ``BoxPicture(image, half, top)`` (a box's faces), ``SpherePicture(image)`` (longitude/latitude),
  ``Planks(grain, tone, ...)`` (a plank floor); ``sample_image(image, u, v)`` (bilinear).
- Lighting: one directional light; ``Scene(..., shadows=8, light_spread=0.06)`` adds soft shadows
  (spheres and boxes cast them) and one-sided diffuse light.

Rendering
- ``render(scene, camera, supersample=1, gain=1.0, with_background=True) -> SynthView`` (through the
  camera's lens distortion when it has one) with
  ``image`` (H, W, 3) uint8 BGR, ``depth`` (H, W) float32 z along the optical axis in metres (inf on
  sky), ``silhouette`` (H, W) bool (foreground objects), ``background`` (H, W, 3) uint8 (the view
  with the foreground removed, for background subtraction; None if with_background=False) and
  ``object_id`` (H, W) int16 (index in scene.objects, -1 for sky). A 640x480 view of the default scene
  takes well under a second (numba kernels; the first call in a process compiles or loads them).
- ``render_views(scene, cameras, supersample=1, gains=None, with_background=True) -> list[SynthView]``.
- ``render_moved(scene, still, sphere) -> image``: the same image as ``render(scene, camera).image``,
  casting only the rays a moving sphere can change, from ``still`` (the view without the sphere).

Ready-made scenes and rigs
- ``default_scene()``: the Fig. 3 studio (object group around ``DEFAULT_TARGET`` on a checker floor).
- ``occluder_scene()``: a flat-coloured (textureless) box before a colour-noise wall on a checker floor.
- ``studio_scene()``: the first-run demo's photographic studio (the same object group on a plank stage
  in a green-screen studio, textures from scikit-learn's sample photographs ``sample_photo(name)``, soft
  shadows; ``PHOTO_CREDITS``).
- ``default_arc_rig(n=10, arc_deg=90, radius=2.5, elevation=1.3, target=DEFAULT_TARGET, width=640,
  height=480, fov_deg=50, prefix="cam", dist=None) -> list[Camera]``: n cameras on an arc (names cam00..;
  ``dist`` gives every camera that lens distortion).
- ``arc_camera(angle_deg, ...)``: one camera on that circle at any angle (virtual views between rig
  cameras); ``arc_angles(n, arc_deg)``: the rig cameras' angles.
- ``camera_gains(n, spread=0.06, seed=0)``: per-camera exposure/white-balance gains for ``gains=``.
- ``city_scene(seed=0, extent=200, n_buildings=40, ...)``: textured ground z = 0 with box buildings,
  for synthetic drone flights (e.g. ``Camera.look_at(name, eye=(x, y, 60), target=(x, y, 0),
  up=(0, 1, 0), fov_deg=80, width=1200, height=900)`` for a nadir view).
"""
from .raycast import SynthView, render, render_moved, render_views
from .rigs import (DEFAULT_TARGET, PHOTO_CREDITS, arc_angles, arc_camera, camera_gains, city_scene, default_arc_rig,
                   default_scene, occluder_scene, sample_photo, studio_scene)
from .scene import Box, Material, Plane, Scene, Sphere
from .textures import (BoxPicture, Checker, ColorNoise, Noise, Picture, Planks, Solid, SpherePicture, fractal_noise,
                       sample_image)

__all__ = [
    "Box", "BoxPicture", "Checker", "ColorNoise", "DEFAULT_TARGET", "Material", "Noise", "PHOTO_CREDITS", "Picture",
    "Plane", "Planks", "Scene", "Solid", "Sphere", "SpherePicture", "SynthView", "arc_angles", "arc_camera",
    "camera_gains", "city_scene", "default_arc_rig", "default_scene", "fractal_noise", "occluder_scene", "render", "render_moved",
    "render_views",
    "sample_image", "sample_photo", "studio_scene",
]
