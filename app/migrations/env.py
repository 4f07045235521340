"""Alembic environment: migrations run in-process at start-up on the connection given in
``config.attributes["connection"]`` (see app.migrate)."""
from __future__ import annotations

from alembic import context

import app.keys  # noqa: F401 - declares the api_keys table on the same metadata
from app.jobstore import Base

connection = context.config.attributes["connection"]
context.configure(connection=connection, target_metadata=Base.metadata, render_as_batch=True)
with context.begin_transaction():
    context.run_migrations()
