"""The planning library: collision-free steps for many units on a grid (PIBT, LaCAM, guidance).

Pure, and importing nothing else of the coordinator: the coordinator and the benchmarks use it as
a library.
"""
