"""Simulated units and sessions: window means of a multi-position design and every sample of a session."""
