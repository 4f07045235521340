"""Camera rigs for virtual views: add one from its calibration, list, read and delete them.

A thin adapter: the calibration formats are read by :func:`workers.sweep.rig_io.load_uploaded_rig`; recordings
and renders are :mod:`app.routers.recordings`, sessions :mod:`app.routers.sessions`, sockets
:mod:`app.routers.rig_sockets`.
"""
from __future__ import annotations

import asyncio
from typing import Any

from fastapi import APIRouter, Depends, File, Form, UploadFile
from fastapi.responses import JSONResponse, Response
from pydantic import BaseModel, Field

from app.auth import principal, require_key
from app.keys import Principal
from app.errors import ApiError
from app.stored_rigs import (delete_recording_data, load_rig, recording_views, rig_meta_or_404, rig_readable,
                            session_config)
from app.routers.recordings import RecordingOut
from app.services import Services, run_compute, services
from app.uploads import check_size
from workers.storage import safe_name
from workers.streaming import actor
from workers.streaming import store as rigstore
from workers.streaming.browser import live_background_atlas
from workers.streaming.viewpoint import orbit_frame
from workers.sweep.rig import Rig
from workers.sweep.rig_io import load_uploaded_rig, rig_to_dict

router = APIRouter(prefix="/v1/rigs", tags=["rigs"], dependencies=[Depends(require_key)])

CALIBRATION_HELP = ("calibration file(s): our rig JSON (.json), a plain camera list (.json: {\"cameras\": [{name, K, "
                    "distCoef, R, t, resolution}]}, as CMU Panoptic's calibration_*.json), OpenCV FileStorage "
                    "(.yml/.yaml/.xml), a Middlebury *_par.txt (give width and height), or COLMAP text (cameras.txt + "
                    "images.txt)")
UNITS_HELP = ("the unit of the calibration's translations t: m, cm, mm, or a positive number of metres per unit "
              "(e.g. 0.0254 for inches); default: cm for a plain camera list (CMU Panoptic's), m for every other "
              "format. The stored rig is in metres.")


class RigSummary(BaseModel):
    id: str
    name: str
    created_at: str
    format: str
    demo: bool = False
    cameras: int


class RigOut(RigSummary):
    calibration: dict[str, Any] = Field(description="the rig in our JSON format (cameras with K, R, t, size)")
    orbit: dict[str, Any] = Field(description="the orbit frame viewers start from: target, up, home elevation "
                                              "and distance, each camera's azimuth and elevation (degrees)")
    recordings: list[RecordingOut]


class RigList(BaseModel):
    rigs: list[RigSummary]


def _summary(meta: dict[str, Any]) -> dict[str, Any]:
    return {"id": meta["id"], "name": meta.get("name") or meta["id"], "created_at": meta["created_at"],
            "format": meta.get("format", "json"), "demo": bool(meta.get("demo")), "cameras": meta["cameras"]}


@router.post("", status_code=201, response_model=RigOut, summary="Add a camera rig from its calibration")
async def create_rig(
    files: list[UploadFile] = File(..., description=CALIBRATION_HELP),
    name: str | None = Form(None, max_length=200, description="a name to show (default: the file name)"),
    width: int | None = Form(None, ge=1, le=65535, description="image width (Middlebury *_par.txt only)"),
    height: int | None = Form(None, ge=1, le=65535, description="image height (Middlebury *_par.txt only)"),
    units: str | None = Form(None, max_length=32, description=UNITS_HELP),
    camera_type: str | None = Form(None, max_length=64, description="plain camera list only: keep the cameras "
                                                                    "of this type (e.g. hd of CMU Panoptic's "
                                                                    "vga, hd and kinect-color)"),
    svc: Services = Depends(services),
    who: Principal = Depends(principal),
) -> JSONResponse:
    for f in files:
        check_size(f, svc.settings.max_upload_bytes)
    contents = [(safe_name(f.filename or "rig.json", "rig.json"), await f.read()) for f in files]
    rig, fmt = await run_compute(svc, load_uploaded_rig, contents, width, height, units, camera_type,
                                 svc.settings.max_rig_cameras, svc.settings.max_image_pixels)
    rig_id = rigstore.new_rig_id()
    meta = await asyncio.to_thread(rigstore.save_rig, svc.store, rig_id, rig,
                                   {"name": name or contents[0][0], "format": fmt, "demo": False,
                                    "created_by": who.id})
    body = RigOut.model_validate(await _rig_out(svc, meta, rig)).model_dump(mode="json")
    return JSONResponse(body, 201, headers={"Location": f"/v1/rigs/{rig_id}"})


async def _rig_out(svc: Services, meta: dict[str, Any], rig: Rig) -> dict[str, Any]:
    return {**_summary(meta), "calibration": rig_to_dict(rig),
            "orbit": await run_compute(svc, lambda: orbit_frame(rig).to_dict()),
            "recordings": await recording_views(svc, meta["id"])}


@router.get("", response_model=RigList, summary="List rigs, newest first",
            description="The key's own rigs and the demo rig (an admin key: every rig).")
async def list_rigs(svc: Services = Depends(services), who: Principal = Depends(principal)) -> dict[str, Any]:
    metas = await asyncio.to_thread(rigstore.list_rig_metas, svc.store)
    return {"rigs": [_summary(m) for m in metas if rig_readable(m, who)]}


@router.get("/{rig_id}", response_model=RigOut, summary="One rig: calibration, orbit frame, recordings")
async def get_rig(rig_id: str, svc: Services = Depends(services), who: Principal = Depends(principal)) -> dict[str, Any]:
    meta = await rig_meta_or_404(svc, rig_id, who)
    return await _rig_out(svc, meta, await load_rig(svc, rig_id))


@router.get("/{rig_id}/live/background", response_class=Response,
            summary="The live stream's background model, for viewers that render in their browser",
            description="Every camera's empty-scene image as the rig's live session models it now, at the cameras' "
                        "calibrated size, as one lossless PNG atlas (the layout of a recording's frame sets, "
                        "`render.atlas_columns` per row). A browser-rendering viewer of the live stream starts its own "
                        "model from it and then follows the frame sets flagged as background. 404 while the session "
                        "has no model (no background set has arrived).",
            responses={200: {"content": {"image/png": {}}}})
async def get_live_background(rig_id: str, svc: Services = Depends(services),
                              who: Principal = Depends(principal)) -> Response:
    await rig_meta_or_404(svc, rig_id, who)
    rig = await load_rig(svc, rig_id)
    client = actor.SessionClient(session_config(svc, rig_id, actor.LIVE), svc.settings.session_resources)
    pngs = await client.background_pngs()
    if pngs is None:
        raise ApiError(404, f"rig {rig_id}'s live stream has no background model yet: send a frame set flagged "
                            f"\"background\" (the empty scene)", "no_background")
    data = await run_compute(svc, live_background_atlas, pngs, rig)
    return Response(data, media_type="image/png", headers={"Cache-Control": "no-store"})


@router.delete("/{rig_id}", status_code=204, response_class=Response,
               summary="Delete a rig with its recordings; its sessions end", responses={403: {"description": "the rig is the demo rig, which only an admin key may change"}})
async def delete_rig(rig_id: str, svc: Services = Depends(services), who: Principal = Depends(principal)) -> Response:
    await rig_meta_or_404(svc, rig_id, who, change=True)
    await asyncio.to_thread(actor.end_sessions, rig_id)
    for recording in await recording_views(svc, rig_id):
        await delete_recording_data(svc, rig_id, recording)
    await asyncio.to_thread(rigstore.delete_rig, svc.store, rig_id)
    return Response(status_code=204)
