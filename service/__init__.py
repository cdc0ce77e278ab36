"""The onboard service: CLI, storage, scheduling, API and publication (the only side effects)."""
