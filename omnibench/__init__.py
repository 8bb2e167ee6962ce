"""omnibench: a test bench for the Omnibot four-mecanum-wheel robot.

Layers (each knows nothing of the ones after it):
model (physics) -> link (bytes on a serial port) -> sim (the simulated board) ->
bench (procedures talking to a board interface) -> runs (run directories) ->
analysis (fit, validate, diagnose; reads run files only) -> cli.
"""

__version__ = "0.1.0"
