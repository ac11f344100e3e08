"""Benchmarks: the planner on public MAPF instances, and the whole system over a real broker."""
