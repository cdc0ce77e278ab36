"""The shore service of the fleet (docs/fleet.md): every vessel's history in one database.

One idea per module: :mod:`.config` (shore.toml), :mod:`.schema` (the tables),
:mod:`.migrations` (their Alembic revisions), :mod:`.store` (the repository), :mod:`.batch`
(reading and checking one ingest batch, format 1), :mod:`.api` (the FastAPI app),
:mod:`.server` (uvicorn around it). The commands are ``recal fleet serve`` and
``recal fleet add-unit`` (service/cli/fleet.py).
"""
