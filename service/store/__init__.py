"""The durable job store: SQLAlchemy 2 tables, Alembic migrations, and the job repository."""

from .db import make_engine, migrate
from .repo import JobStore

__all__ = ["JobStore", "make_engine", "migrate"]
