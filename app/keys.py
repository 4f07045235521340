"""API keys and the principals they stand for.

A request's principal is who acts: a managed key (created with ``sweepcast keys create`` or ``POST /v1/keys``,
stored only as the SHA-256 of its secret in the job table's database, so every replica shares it), or the
service's own keys (``SWEEPCAST_API_KEYS``), which act as the admin principal. With no key of either kind the
service has no authentication and every caller is the admin principal (loopback only, see ``sweepcast serve``).

A managed key is looked up in the database on every request (one indexed point query): a revoked or expired key
fails at once on every replica, with no cache to outlive it.
"""
from __future__ import annotations

import datetime as dt
import hashlib
import hmac
import secrets
import uuid
from dataclasses import dataclass
from typing import Any, Literal

from sqlalchemy import JSON, DateTime, String, or_, select
from sqlalchemy.engine import Engine
from sqlalchemy.orm import Mapped, mapped_column, sessionmaker

from app.jobstore import ADMIN, Base, as_utc, utcnow

Role = Literal["user", "admin"]
SECRET_PREFIX = "sck_"
"""Every managed key's secret starts with this (secret scanners and people can tell what leaked)."""


@dataclass(frozen=True)
class Principal:
    """Who a request acts for: ``id`` is what resources record as their creator."""

    id: str
    name: str
    role: Role
    quota: dict[str, float] | None = None
    """This key's quota overrides (:mod:`app.quotas` names the fields); None: the settings' defaults."""

    @property
    def label(self) -> str:
        """How logs name the key: its name, and its id when that differs (never its secret)."""
        return self.name if self.id == self.name else f"{self.name} ({self.id})"

    @property
    def is_admin(self) -> bool:
        return self.role == "admin"

    def owns(self, created_by: str | None) -> bool:
        """True when this principal may see and change a resource created by ``created_by`` (None: before owners
        were recorded, which is the admin's)."""
        return self.is_admin or (created_by or ADMIN) == self.id


SERVICE_ADMIN = Principal(ADMIN, "admin", "admin")
"""The principal of SWEEPCAST_API_KEYS and of a service without keys."""


class ApiKey(Base):
    __tablename__ = "api_keys"

    id: Mapped[str] = mapped_column(String(32), primary_key=True)
    name: Mapped[str] = mapped_column(String(100), index=True)
    role: Mapped[str] = mapped_column(String(16))
    secret_sha256: Mapped[str] = mapped_column(String(64), unique=True, index=True)
    quota: Mapped[dict[str, Any] | None] = mapped_column(JSON, nullable=True)
    created_at: Mapped[dt.datetime] = mapped_column(DateTime(timezone=True), default=utcnow)
    expires_at: Mapped[dt.datetime | None] = mapped_column(DateTime(timezone=True), nullable=True)
    revoked_at: Mapped[dt.datetime | None] = mapped_column(DateTime(timezone=True), nullable=True)

    def active(self, now: dt.datetime) -> bool:
        expires = as_utc(self.expires_at)
        return self.revoked_at is None and (expires is None or expires > now)

    def principal(self) -> Principal:
        return Principal(self.id, self.name, "admin" if self.role == "admin" else "user", self.quota or None)

    def public(self) -> dict[str, Any]:
        """The key as the API and the CLI show it: never its secret or hash."""
        return {"id": self.id, "name": self.name, "role": self.role, "quota": self.quota or {},
                "created_at": as_utc(self.created_at), "expires_at": as_utc(self.expires_at),
                "revoked_at": as_utc(self.revoked_at), "active": self.active(utcnow())}


def secret_hash(secret: str) -> str:
    """SHA-256 (hex) of a key's secret: a random 256-bit token needs no slow password hash."""
    return hashlib.sha256(secret.encode()).hexdigest()


def new_secret() -> str:
    return SECRET_PREFIX + secrets.token_urlsafe(32)


class UnknownKey(LookupError):
    """No such key (the CLI and the route say so)."""


class KeyStore:
    """Every read and write of the ``api_keys`` table (the job table's database). Blocking: call off the loop."""

    def __init__(self, engine: Engine) -> None:
        self._engine = engine
        self._session = sessionmaker(engine, expire_on_commit=False)

    def create(self, name: str, role: Role = "user", expires_at: dt.datetime | None = None,
               quota: dict[str, float] | None = None) -> tuple[ApiKey, str]:
        """A new key and its secret (shown once: only its hash is kept)."""
        secret = new_secret()
        key = ApiKey(id="key_" + uuid.uuid4().hex[:16], name=name, role=role, secret_sha256=secret_hash(secret),
                     quota=quota or None, created_at=utcnow(), expires_at=expires_at)
        with self._session.begin() as s:
            s.add(key)
        return key, secret

    def list(self) -> list[ApiKey]:
        with self._session() as s:
            return list(s.scalars(select(ApiKey).order_by(ApiKey.created_at, ApiKey.id)))

    def get(self, key_id: str) -> ApiKey:
        with self._session() as s:
            key = s.get(ApiKey, key_id)
        if key is None:
            raise UnknownKey(f"no key with id {key_id!r}")
        return key

    def find(self, key_id_or_name: str) -> ApiKey:
        """A key by id, else the one active key of that name."""
        try:
            return self.get(key_id_or_name)
        except UnknownKey:
            pass
        now = utcnow()
        named = [k for k in self.list() if k.name == key_id_or_name and k.active(now)]
        if len(named) != 1:
            raise UnknownKey(f"no key with id {key_id_or_name!r}" if not named else
                            f"{len(named)} active keys are named {key_id_or_name!r}: give the id")
        return named[0]

    def revoke(self, key_id: str) -> ApiKey:
        """Revoke a key: every replica refuses it from the next request on. Revoking twice is harmless."""
        with self._session.begin() as s:
            key = s.get(ApiKey, key_id, with_for_update=True)
            if key is None:
                raise UnknownKey(f"no key with id {key_id!r}")
            key.revoked_at = key.revoked_at or utcnow()
        return key

    def rotate(self, key_id: str) -> tuple[ApiKey, str]:
        """A new secret for a key (same id, name, role and owned resources); the old secret fails at once."""
        secret = new_secret()
        with self._session.begin() as s:
            key = s.get(ApiKey, key_id, with_for_update=True)
            if key is None or key.revoked_at is not None:
                raise UnknownKey(f"no active key with id {key_id!r}")
            key.secret_sha256 = secret_hash(secret)
        return key, secret

    def any(self) -> bool:
        """True once any key was ever created (revoked ones included): from then on, requests need a key."""
        with self._session() as s:
            return s.scalar(select(ApiKey.id).limit(1)) is not None

    def lookup(self, secret: str) -> Principal | None:
        """The principal of an active key with this secret, else None: one indexed query (Core, no ORM session:
        it runs on every request)."""
        table = ApiKey.__table__
        query = select(table.c.id, table.c.name, table.c.role, table.c.quota).where(
            table.c.secret_sha256 == secret_hash(secret), table.c.revoked_at.is_(None),
            or_(table.c.expires_at.is_(None), table.c.expires_at > utcnow()))
        with self._engine.connect() as conn:
            row = conn.execute(query).first()
        return None if row is None else Principal(row.id, row.name, "admin" if row.role == "admin" else "user",
                                                  row.quota or None)


def env_key_matches(presented: str, keys: list[str]) -> bool:
    """True when ``presented`` is one of the service's own keys (compared in constant time)."""
    return any(hmac.compare_digest(presented.encode(), k.encode()) for k in keys)
