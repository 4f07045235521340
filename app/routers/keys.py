"""API keys: an admin creates, lists, revokes and rotates them; every key reads its own limits and usage."""
from __future__ import annotations

import asyncio
import datetime as dt
from typing import Any, Literal

from fastapi import APIRouter, Depends
from fastapi.responses import JSONResponse, Response
from pydantic import BaseModel, ConfigDict, Field

from app.auth import principal, require_admin, require_key
from app.errors import ApiError
from app.jobstore import ADMIN
from app.keys import UnknownKey, Principal
from app.services import Services, services

router = APIRouter(prefix="/v1/keys", tags=["keys"], dependencies=[Depends(require_key)])


class QuotaOverrides(BaseModel):
    """A key's own limits; a field left out (or null) takes the service's default (``SWEEPCAST_QUOTA_*``)."""

    model_config = ConfigDict(extra="forbid")
    stored_bytes: int | None = Field(None, ge=1, le=2**62, description="bytes of uploads and results kept")
    active_jobs: int | None = Field(None, ge=1, le=1_000_000, description="jobs queued or running at once")
    viewer_sessions: int | None = Field(None, ge=1, le=1_000_000, description="viewer sockets open per API replica")
    uploads_per_minute: int | None = Field(None, ge=1, le=1_000_000, description="uploads per minute per API replica")

    def stored(self) -> dict[str, int] | None:
        return {k: v for k, v in self.model_dump().items() if v is not None} or None


class KeyCreate(BaseModel):
    model_config = ConfigDict(extra="forbid")
    name: str = Field(min_length=1, max_length=100, pattern=r"^[\w.@ -]+$",
                      description="who or what uses the key (the access log names it)")
    role: Literal["user", "admin"] = Field("user", description="user: sees its own resources; admin: all, and keys")
    expires_at: dt.datetime | None = Field(None, description="when the key stops working (ISO 8601 with a zone)")
    quota: QuotaOverrides = Field(default_factory=QuotaOverrides)


class KeyOut(BaseModel):
    id: str
    name: str
    role: Literal["user", "admin"]
    quota: dict[str, int] = Field(description="the key's own limits (others: the service's defaults)")
    created_at: dt.datetime | None
    expires_at: dt.datetime | None
    revoked_at: dt.datetime | None
    active: bool


class KeySecret(KeyOut):
    secret: str = Field(description="the bearer secret: shown this once, stored only as its SHA-256")


class KeyList(BaseModel):
    keys: list[KeyOut]


class KeyUsage(BaseModel):
    id: str
    name: str
    role: Literal["user", "admin"]
    limits: dict[str, int | None] = Field(description="stored_bytes, active_jobs, viewer_sessions, "
                                                      "uploads_per_minute (null: no limit)")
    usage: dict[str, int] = Field(description="the same quantities now (viewers and uploads on this replica)")


@router.get("/me", response_model=KeyUsage, summary="The calling key: its role, its limits and what it uses now")
async def my_key(svc: Services = Depends(services), who: Principal = Depends(principal)) -> dict[str, Any]:
    return {"id": who.id, "name": who.name, "role": who.role, "limits": svc.quotas.limits(who).as_dict(),
            "usage": await svc.quotas.usage(who)}


@router.delete("/me", status_code=204, response_class=Response,
               summary="Revoke the calling key itself (a key that leaked): it fails from the next request on",
               responses={409: {"description": "the key is one of SWEEPCAST_API_KEYS: remove it from the setting"}})
async def revoke_my_key(svc: Services = Depends(services), who: Principal = Depends(principal)) -> Response:
    if who.id == ADMIN:
        raise ApiError(409, "this key is one of the service's own keys (SWEEPCAST_API_KEYS, or no keys at all): remove "
                            "it from the setting and restart instead", "service_key")
    await asyncio.to_thread(svc.keys.revoke, who.id)
    return Response(status_code=204)


@router.get("", response_model=KeyList, summary="Every managed key (admin keys only); never their secrets",
            responses={403: {"description": "the key is not an admin key"}})
async def list_keys(svc: Services = Depends(services), _: Principal = Depends(require_admin)) -> dict[str, Any]:
    return {"keys": [k.public() for k in await asyncio.to_thread(svc.keys.list)]}


@router.post("", status_code=201, response_model=KeySecret,
             summary="Create a key (admin keys only): its secret is in this answer and nowhere else",
             responses={403: {"description": "the key is not an admin key"}})
async def create_key(body: KeyCreate, svc: Services = Depends(services),
                     _: Principal = Depends(require_admin)) -> JSONResponse:
    if body.expires_at is not None and body.expires_at.tzinfo is None:
        raise ApiError(422, "expires_at needs a time zone (e.g. 2027-01-31T00:00:00Z)", "invalid_parameters")
    key, secret = await asyncio.to_thread(svc.keys.create, body.name, body.role, body.expires_at, body.quota.stored())
    out = KeySecret.model_validate({**key.public(), "secret": secret}).model_dump(mode="json")
    return JSONResponse(out, 201, headers={"Location": f"/v1/keys/{key.id}"})


@router.post("/{key_id}/rotate", response_model=KeySecret,
             summary="A new secret for a key (admin keys only): the old one fails at once; its resources stay its",
             responses={403: {"description": "the key is not an admin key"}})
async def rotate_key(key_id: str, svc: Services = Depends(services),
                     _: Principal = Depends(require_admin)) -> dict[str, Any]:
    try:
        key, secret = await asyncio.to_thread(svc.keys.rotate, key_id)
    except UnknownKey as exc:
        raise ApiError(404, str(exc), "key_not_found") from None
    return {**key.public(), "secret": secret}


@router.delete("/{key_id}", status_code=204, response_class=Response,
               summary="Revoke a key (admin keys only): every replica refuses it from the next request on",
               responses={403: {"description": "the key is not an admin key"}})
async def revoke_key(key_id: str, svc: Services = Depends(services), _: Principal = Depends(require_admin)) -> Response:
    try:
        await asyncio.to_thread(svc.keys.revoke, key_id)
    except UnknownKey as exc:
        raise ApiError(404, str(exc), "key_not_found") from None
    return Response(status_code=204)
