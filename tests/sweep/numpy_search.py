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
