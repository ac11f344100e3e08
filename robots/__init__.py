"""Simulated units of gridfleet and the world simulation they live in."""
