"""The virtual-view sessions alive in the cluster (one actor per rig and source; see :mod:`workers.streaming.actor`)."""
from __future__ import annotations

import asyncio
from typing import Any

from fastapi import APIRouter, Depends
from pydantic import BaseModel, Field

from app.auth import require_key
from app.services import Services, services
from workers.streaming import actor

router = APIRouter(prefix="/v1/sessions", tags=["rigs"], dependencies=[Depends(require_key)])


class SessionOut(BaseModel):
    name: str
    rig_id: str
    source: str
    info: dict[str, Any] | None = Field(None, description="viewers, renders, frames, ... (None: not answering)")


class SessionList(BaseModel):
    sessions: list[SessionOut]


@router.get("", response_model=SessionList, summary="The virtual-view sessions alive in the cluster")
async def list_sessions(svc: Services = Depends(services)) -> dict[str, Any]:
    found = await asyncio.to_thread(actor.list_sessions)
    infos = await asyncio.gather(*[asyncio.to_thread(actor.session_info, s["name"]) for s in found])
    return {"sessions": [{**s, "info": info} for s, info in zip(found, infos)]}
