"""The depth search's definition in plain numpy, the reference the compiled searches are tested against."""
import numpy as np


def plane_costs(cameras, images, sils, virtual, s_planes, bits, trunc2=0.0, min_views=2):
    """Cost (P, h, w) of every plane by the kernels' definition, inf where the plane is not a candidate:
    positions rounded to 1/2**bits px, exact bilinear samples, a camera votes when its four taps are in
    its image, a vote outside the camera's silhouette (nearest pixel) culls the point (sils None: no hull)."""
    h, w = virtual.height, virtual.width
    G = virtual.R.T @ np.linalg.inv(virtual.K)
    xs, ys = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    pix = np.stack([xs, ys, np.ones_like(xs)], axis=-1)
    out = np.full((len(s_planes), h, w), np.inf)
    for j, s in enumerate(s_planes):
        samples, voted, culled = [], [], np.zeros((h, w), bool)
        for i, cam in enumerate(cameras):
            M, p = cam.P[:, :3], cam.P[:, 3]
            hom = pix @ (M @ G).T + s * (M @ virtual.center + p)
            with np.errstate(divide="ignore", invalid="ignore"):
                u, v = hom[..., 0] / hom[..., 2], hom[..., 1] / hom[..., 2]
            qu, qv = np.rint(u * 2**bits) / 2**bits, np.rint(v * 2**bits) / 2**bits
            ok = (hom[..., 2] > 1e-9) & (qu >= 0) & (qv >= 0) & (qu <= cam.width - 1) & (qv <= cam.height - 1)
            x0 = np.where(ok, np.floor(qu), 0).astype(int)
            y0 = np.where(ok, np.floor(qv), 0).astype(int)
            fx, fy = (np.where(ok, qu - x0, 0)[..., None], np.where(ok, qv - y0, 0)[..., None])
            x1, y1 = np.minimum(x0 + 1, cam.width - 1), np.minimum(y0 + 1, cam.height - 1)
            img = images[i].astype(float)
            top = img[y0, x0] + fx * (img[y0, x1] - img[y0, x0])
            bot = img[y1, x0] + fx * (img[y1, x1] - img[y1, x0])
            samples.append(top + fy * (bot - top))
            voted.append(ok)
            if sils is not None:
                nu = np.clip(np.rint(np.where(ok, u, 0)), 0, cam.width - 1).astype(int)
                nv = np.clip(np.rint(np.where(ok, v, 0)), 0, cam.height - 1).astype(int)
                culled |= ok & ~sils[i][nv, nu]
        c = np.stack(samples)  # (N, h, w, 3)
        ok = np.stack(voted)
        n = ok.sum(axis=0)
        mean = (c * ok[..., None]).sum(axis=0) / np.maximum(n, 1)[..., None]
        dev = (((c - mean) ** 2).sum(axis=-1)) * ok
        if trunc2 > 0:
            dev = np.minimum(dev, trunc2) * ok
        cost = dev.sum(axis=0) / np.maximum(n, 1)
        out[j] = np.where((n >= min_views) & ~culled, cost, np.inf)
    return out


def best_plane(costs):
    best = np.argmin(costs, axis=0)  # the first of equal costs: the nearer plane
    return np.where(np.isfinite(costs.min(axis=0)), best, -1)


def confirmations(cameras, virtual, s_planes, cost, best, tol_px=1):
    """The cross-view check (workers.sweep.occlusion) in numpy: per virtual pixel, how many cameras' own choices
    confirm its plane ``best`` (h, w). cost (h, w, P), inf where not a candidate. Each camera pixel is won by the
    least-cost hypothesis (y, x, j) whose point it sees nearest (ties to the first in (y, x, j) order); a camera
    confirms a pixel when the winner of the pixel its point at ``best`` lands on lies within tol_px of it."""
    h, w, P = cost.shape
    G = virtual.R.T @ np.linalg.inv(virtual.K)
    xs, ys = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    pix = np.stack([xs, ys, np.ones_like(xs)], axis=-1)
    yi, xi = np.mgrid[:h, :w]
    out = np.zeros((h, w), int)
    for cam in cameras:
        M, p = cam.P[:, :3], cam.P[:, 3]
        hom = pix[:, :, None, :] @ (M @ G).T + s_planes[None, None, :, None] * (M @ virtual.center + p)  # h w P 3
        with np.errstate(divide="ignore", invalid="ignore"):
            u, v = hom[..., 0] / hom[..., 2], hom[..., 1] / hom[..., 2]
        ok = (hom[..., 2] > 1e-9) & (u >= 0) & (v >= 0) & (u <= cam.width - 1) & (v <= cam.height - 1)
        key = np.where(ok, np.floor(np.where(ok, v, 0) + 0.5) * cam.width + np.floor(np.where(ok, u, 0) + 0.5), -1)
        key = key.astype(np.int64).ravel()
        flat = cost.ravel()
        idx = np.flatnonzero((key >= 0) & np.isfinite(flat))
        order = idx[np.lexsort((idx, flat[idx], key[idx]))]
        first = np.r_[True, key[order][1:] != key[order][:-1]][:len(order)]
        winner = np.full(cam.width * cam.height, -1, np.int64)
        winner[key[order][first]] = order[first] // P  # the winning virtual pixel, y * w + x
        mine = key.reshape(h, w, P)[yi, xi, np.maximum(best, 0)]
        wp = winner[np.maximum(mine, 0)]
        out += (best >= 0) & (mine >= 0) & (wp >= 0) & (np.abs(wp // w - yi) <= tol_px) & (np.abs(wp % w - xi) <= tol_px)
    return out
