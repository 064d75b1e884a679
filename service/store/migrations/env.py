"""Alembic environment: runs on the connection handed over by service.store.db.migrate."""

from __future__ import annotations

from alembic import context

from service.store.tables import metadata

config = context.config
connection = config.attributes.get("connection")
if connection is None:  # pragma: no cover - only migrate() drives these migrations
    raise RuntimeError("run migrations through service.store.db.migrate(engine)")
context.configure(connection=connection, target_metadata=metadata, render_as_batch=True)
with context.begin_transaction():
    context.run_migrations()
