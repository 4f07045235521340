"""Depth-map post-filtering for 3D video (Lee, Yang & Oh) and the view synthesis that judges it.

Modules: ``levels`` (inverse-depth levels <-> metres), ``upsample`` (decoder-side resizing),
``filters`` (dilation, modified dilation, morphological clean-up), ``edge_aware`` (weighted mode
filter), ``methods`` (the ``METHODS`` registry and the decode-side pipeline), ``pipeline`` (the
same at frame rate with reused buffers), ``dibr`` (view synthesis), ``metrics`` (PSNR, SSIM, depth
error, edge band), ``io`` (PNG/PGM, YUV, MPEG camera files), ``params`` (request models),
``service`` (bytes in/out), ``job`` (the video job), ``cli``.
"""
from .errors import DepthInputError
from .methods import METHODS, FilterOptions, apply_method, postprocess

__all__ = ["METHODS", "DepthInputError", "FilterOptions", "apply_method", "postprocess"]
