"""Depth maps of multi-view-plus-depth video: post-filter one map, a whole sequence, synthesise a view."""
from __future__ import annotations

import base64
from typing import Callable, TypeVar

import cv2

from fastapi import APIRouter, Depends, File, UploadFile
from fastapi.responses import JSONResponse, Response
from pydantic import BaseModel, Field

from app.auth import principal, require_key
from app.keys import Principal
from app.errors import ApiError
from app.limits import BATCH_BODY
from app.routers.jobs import JobOut, job_accepted
from app.params_form import params_form
from app.services import Services, Upload, create_job, run_compute, services
from app.sync_work import BUSY_RESPONSE
from app.uploads import check_size, read_upload
from workers.common.images import ImageInputError, decode_image
from workers.common.work import WorkEstimate
from workers.depth.io import YuvFormat, yuv_sequence_frames
from workers.depth.job import VIDEO_JOB, check_video_input
from workers.depth.params import DepthFilterParams, DepthVideoParams, SynthesizeParams
from workers.depth.encoded import filter_depth_bytes, filter_work, synthesis_work, synthesize_bytes
from workers.depth.upsample import target_size
from workers.depth.video import probe_depth_video

NOT_AN_IMAGE = "an upload is not an image in a format this route reads"
TOO_MUCH_WORK = ("the request body, or one upload in it, is over the service's limit, an image is over the pixel "
                 "limit, or the request's estimated CPU time or memory is over SWEEPCAST_SYNC_MAX_CPU_SECONDS / "
                 "SWEEPCAST_SYNC_MAX_MEMORY_MB (error too_much_work: the detail says what to do instead)")
FILTER_INSTEAD = ("send it as a job instead: POST /v1/depth/videos with the depth as a one-frame raw YUV sequence "
                  "(params width and height, the same method and sizes; a texture as one 8-bit 4:2:0 frame), or ask "
                  "for a cheaper method or a smaller output")
SYNTHESIS_INSTEAD = "synthesise a smaller view (downscale the views, or give the target camera a smaller size)"
router = APIRouter(prefix="/v1/depth", tags=["depth"], dependencies=[Depends(require_key)])

R = TypeVar("R")
SCHEMA_NAMED = " (see the schema of that name); default {}"


class SynthesisOut(BaseModel):
    image_png: str = Field(description="the synthesised view, PNG, base64")
    holes_png: str = Field(description="8-bit mask, 255 where no source view saw the pixel (before hole filling), PNG, base64")
    holes_fraction: float = Field(description="share of pixels no source view saw")


@router.post("/filter", response_class=Response,
             summary="Upsample and post-filter one depth map (PNG/PGM, 8 or 16 bit) -> filtered depth PNG",
             responses={200: {"content": {"image/png": {}}}, 413: {"description": TOO_MUCH_WORK},
                        415: {"description": NOT_AN_IMAGE}, 503: BUSY_RESPONSE})
async def filter_depth(
    depth: UploadFile = File(..., description="decoded depth map: PNG or PGM, 8 or 16 bit inverse-depth levels"),
    texture: UploadFile | None = File(None, description="texture at the output size (guided methods: wmf)"),
    p: DepthFilterParams = params_form(DepthFilterParams, SCHEMA_NAMED),
    svc: Services = Depends(services),
) -> Response:
    depth_bytes = await read_upload(depth, svc.settings.max_upload_bytes)
    texture_bytes = await read_upload(texture, svc.settings.max_upload_bytes) if texture is not None else None
    limit = svc.settings.max_image_pixels
    out = await _bounded(svc, filter_work(depth_bytes, p, texture_bytes, limit), FILTER_INSTEAD,
                         lambda: filter_depth_bytes(depth_bytes, p, texture_bytes, limit))
    return Response(out, media_type="image/png", headers={"X-Depth-Method": p.method_for(texture is not None)})


@router.post("/synthesize", response_model=SynthesisOut,
             responses={413: {"description": TOO_MUCH_WORK}, 415: {"description": NOT_AN_IMAGE},
                        503: BUSY_RESPONSE},
             summary="Synthesise a virtual view from texture + depth of one or two views (DIBR)")
async def synthesize(
    textures: list[UploadFile] = File(..., description="one texture per source view, in camera order"),
    depths: list[UploadFile] = File(..., description="one depth map per source view, same order"),
    p: SynthesizeParams = params_form(SynthesizeParams, SCHEMA_NAMED, required=True),
    svc: Services = Depends(services),
) -> SynthesisOut:
    if len(textures) != len(depths):
        raise ApiError(422, f"got {len(textures)} textures and {len(depths)} depth maps: give one of each per view",
                       "invalid_request")
    views = [(await read_upload(t, svc.settings.max_upload_bytes), await read_upload(d, svc.settings.max_upload_bytes))
             for t, d in zip(textures, depths)]
    limit = svc.settings.max_image_pixels
    image, holes, fraction = await _bounded(svc, synthesis_work(views, p, limit), SYNTHESIS_INSTEAD,
                                            lambda: _synthesize(views, p, limit))
    return SynthesisOut(image_png=base64.b64encode(image).decode(), holes_png=base64.b64encode(holes).decode(),
                        holes_fraction=fraction)


async def _bounded(svc: Services, work: tuple[WorkEstimate, str] | None, instead: str, compute: Callable[[], R]) -> R:
    """``compute()`` on the compute threads through the gate of synchronous work (:mod:`app.sync_work`): 413 when
    ``work``'s estimate is over one request's limits, else run within the memory budget. ``work`` None (the engine
    refuses the inputs at its first checks): admitted free."""
    estimate, what = work or (WorkEstimate(0.0, 0), "")
    svc.sync_work.check(estimate, what, instead)
    return await svc.sync_work.run(estimate, lambda: run_compute(svc, compute))


def _synthesize(views: list[tuple[bytes, bytes]], p: SynthesizeParams, limit: int) -> tuple[bytes, bytes, float]:
    """(view PNG, hole mask PNG, share of hole pixels): the mask decoded back within the same limit."""
    image, holes = synthesize_bytes(views, p, limit)
    try:
        mask = decode_image(holes, cv2.IMREAD_GRAYSCALE, limit)
    except ImageInputError as exc:  # pragma: no cover - our own PNG, at most the size of a checked input
        raise exc.about("hole mask") from None
    return image, holes, float((mask > 0).mean())


@router.post("/videos", status_code=202, response_model=JobOut, openapi_extra=BATCH_BODY,
             responses={415: {"description": "input_format video: the depth is no 8-bit H.264/HEVC video this route "
                                             "reads"}},
             summary="Post-filter a depth sequence (raw YUV, or H.264/HEVC video): a job with progress per frame",
             description="`input_format` \"yuv\" (default): raw planar frames, `width` and `height` required. "
                         "\"video\": an 8-bit H.264 or HEVC video (raw .264/.265, MP4, MKV, ...) whose luma is the "
                         "depth; its codec, sample format, frame size (`max_image_pixels`) and frame count "
                         "(`max_video_frames`) are checked before the job is made. Results: filtered.yuv, report.json.")
async def filter_video(
    depth: UploadFile = File(..., description="raw planar YUV depth frames (4:0:0 or 4:2:0, 8 or 16 bit LE), "
                                              "or an 8-bit H.264/HEVC depth video (input_format \"video\")"),
    texture: UploadFile | None = File(None, description="8-bit 4:2:0 texture at the output size (guided methods)"),
    p: DepthVideoParams = params_form(DepthVideoParams, SCHEMA_NAMED + "; width and height required for raw YUV",
                                      required=True),
    svc: Services = Depends(services),
    who: Principal = Depends(principal),
) -> JSONResponse:
    uploads = [Upload("depth", depth.file, {"filename": depth.filename})]
    if texture is not None:
        check_size(texture, svc.settings.max_batch_bytes)
        uploads.append(Upload("texture", texture.file, {"filename": texture.filename}))
    if p.input_format == "video":
        await run_compute(svc, _check_video, depth, p, svc)
    else:
        _check_yuv(depth, p, svc.settings.max_video_frames)
    return job_accepted(await create_job(svc, who, VIDEO_JOB, p, uploads))


def _check_yuv(depth: UploadFile, p: DepthVideoParams, max_frames: int) -> None:
    """Refuse at once a sequence whose size is not a whole number of frames, or that has too many (the job's own
    rule: the job would fail anyway)."""
    yuv_sequence_frames(depth.size or 0, YuvFormat(p.width, p.height, p.bits, p.chroma), max_frames,
                        depth.filename or "depth")


def _check_video(depth: UploadFile, p: DepthVideoParams, svc: Services) -> None:
    """Probe a coded depth video (container, codec, 8-bit samples, frame size and count) before a job
    is made of it; its problems are the engine's 4xx (DepthInputError's status)."""
    name = depth.filename or "depth video"
    if not depth.size:
        raise ApiError(400, f"{name} is empty", "empty_file")
    try:
        info = probe_depth_video(depth.file, svc.settings.max_video_frames, svc.settings.max_image_pixels, name)
        check_video_input(info, p)
        target_size((info.height, info.width), p.scale, p.out_size(), svc.settings.max_image_pixels)
    finally:
        depth.file.seek(0)
