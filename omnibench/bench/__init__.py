"""Bench procedures (III.i, III.ii, III.iii, IV): procedure files, the runner, the operator.

Procedures talk to a board interface (omnibench.bench.board), never to bytes, and write
run directories (omnibench.runs).
"""
