"""Worlds for testing: robot physics written independently of `omnibench.model` (the fit's own
simulator), so diagnosis and fits are measured on data the model did not make.

Knows `omnibench.model` (robot description, scenario, geometry) only; used by the simulated
board's plant (omnibench.sim) and by simulated campaigns (omnibench.analysis.simcampaign).
"""
