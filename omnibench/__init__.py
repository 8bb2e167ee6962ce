"""omnibench: a test bench for the Omnibot four-mecanum-wheel robot.

Layers, lowest first (each knows nothing of the ones after it; docs/architecture.md,
checked by tests/test_layers.py):
base (errors, files, resources, locks) -> model (physics) -> effects (terms registered into the
model) -> worlds, link (bytes on a serial port), procedures (plans), runs (run directories) ->
sim (the simulated board), bench (one procedure on a board), analysis (fit, validate, diagnose,
design; reads run files only) -> campaign (bench then analysis, reports) -> cli.
"""

__version__ = "0.1.0"
