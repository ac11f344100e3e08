"""Helpers for tests of gridfleet and of software that talks to it (brokers, waiting)."""
