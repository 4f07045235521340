"""What the sweep benchmark's questions share: the colour weightings compared, the procedural scene's depth
range, and interleaved timing (:func:`interleaved`)."""
from __future__ import annotations

import time

import cv2
import numpy as np

from workers.camera import Camera
from workers.sweep.renderer import RenderResult, SweepRenderer
from workers.sweep.rig import Rig
from workers.sweep.rig_io import rectified_rig

# name -> weighting options; d_bnd of kojima is set per scene from the camera spacing
METHODS = {
    "global": {"method": "global"},
    "nearest": {"method": "nearest"},
    "ulr2": {"method": "ulr", "k": 2},
    "ulr3": {"method": "ulr", "k": 3},
    "ulr4": {"method": "ulr", "k": 4},
    "kojima": {"method": "kojima"},
    "kojima_k": {"method": "kojima_k"},
}
NEAR, FAR = 1.6, 3.6  # the procedural object lies within these depths from the arc
GAIN_SPREAD = 0.06


def all_methods(renderer: SweepRenderer, first: RenderResult) -> dict[str, RenderResult]:
    """``first`` re-coloured by every method (one sweep, seven colourings); kojima's and kojima_k's D_bnd is
    the renderer's default, derived from the camera spacing (the same for both)."""
    return {name: renderer.reshade(first, **opts) for name, opts in METHODS.items()}


def all_weights(renderer: SweepRenderer, first: RenderResult) -> dict[str, np.ndarray]:
    """Per method, every camera's weight at every pixel of ``first`` ((h, w, N) float32; see
    :meth:`SweepRenderer.blend_weights`)."""
    return {name: renderer.blend_weights(first, **opts) for name, opts in METHODS.items()}



# --- speed --------------------------------------------------------------------------------------
def clocked(fn) -> tuple[float, float, object]:
    """(wall s, CPU s of this process (all threads), result) of one call."""
    c0, t0 = time.process_time(), time.perf_counter()
    res = fn()
    return time.perf_counter() - t0, time.process_time() - c0, res


def interleaved(fns: dict, reps: dict, warm: tuple[str, ...] = ("render",)) -> dict:
    """Calls each function ``reps[name]`` times (those in ``warm`` once more first, untimed: compiled
    code loads on the first call), interleaved so that the load other users put on the machine
    affects all of them alike. Returns per name the median wall s, the median CPU s and the last result."""
    out = {name: {"wall": [], "cpu": [], "res": fn() if name in warm else None} for name, fn in fns.items()}
    for k in range(max(reps.values())):
        for name, fn in fns.items():
            if k < reps[name]:
                wall, cpu, res = clocked(fn)
                out[name]["wall"].append(wall)
                out[name]["cpu"].append(cpu)
                out[name]["res"] = res
    return {name: {"wall": float(np.median(v["wall"])), "cpu": float(np.median(v["cpu"])), "res": v["res"]}
            for name, v in out.items()}


def leave_one_out(files: dict[int, str], sources: list[int], target: int, w: int, h: int) -> tuple[Rig, Camera]:
    """The rectified rig of views ``sources`` (positions = view numbers) and the held-out camera ``target``."""
    views = sorted(sources + [target])
    rig = rectified_rig([files[k] for k in views], w, h, positions=views)
    inputs = Rig(tuple(c for c, k in zip(rig.cameras, views) if k != target),
                 tuple(f for f, k in zip(rig.image_files, views) if k != target))
    return inputs, rig.cameras[views.index(target)]


def still_between(earlier: np.ndarray, later: np.ndarray) -> np.ndarray:
    """(H, W) bool: the pixels whose true colour is the same in two consecutive true views ((H, W, 3) uint8), away
    from any change (eroded 5 x 5): where a flicker measure looks, since nothing there should change."""
    same = np.abs(later.astype(int) - earlier).max(axis=2) == 0
    return cv2.erode(same.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
