"""Helpers shared by the tests: MQTT probes, waits, browser fixtures."""
