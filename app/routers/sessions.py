"""The virtual-view sessions alive in the cluster (one actor per rig and source; see :mod:`workers.streaming.actor`)."""
from __future__ import annotations

import asyncio
from typing import Any

from fastapi import APIRouter, Depends
from pydantic import BaseModel, Field

from app.auth import principal, require_key
from app.keys import Principal
from app.stored_rigs import rig_readable
from app.services import Services, services
from workers.streaming import actor
from workers.streaming import store as rigstore

router = APIRouter(prefix="/v1/sessions", tags=["rigs"], dependencies=[Depends(require_key)])


class SessionOut(BaseModel):
    name: str
    rig_id: str
    source: str
    info: dict[str, Any] | None = Field(None, description="viewers, renders, frames, ... (None: not answering)")


class SessionList(BaseModel):
    sessions: list[SessionOut]


@router.get("", response_model=SessionList, summary="The virtual-view sessions alive in the cluster",
            description="Those of the rigs the key may see: its own and the demo rig (an admin key: all).")
async def list_sessions(svc: Services = Depends(services), who: Principal = Depends(principal)) -> dict[str, Any]:
    found = await asyncio.to_thread(actor.list_sessions)
    if not who.is_admin:
        metas = {m["id"]: m for m in await asyncio.to_thread(rigstore.list_rig_metas, svc.store)}
        found = [s for s in found if s["rig_id"] in metas and rig_readable(metas[s["rig_id"]], who)]
    infos = await asyncio.gather(*[asyncio.to_thread(actor.session_info, s["name"]) for s in found])
    return {"sessions": [{**s, "info": info} for s, info in zip(found, infos)]}
