"""The onboard service: CLI, storage, scheduling, API and publication (the only side effects)."""

from service import moved  # noqa: F401 - the deprecated paths (service.db) until 0.3.0
