"""Closing the loop: find what the model still gets wrong, name the missing effect, add it,
report the error before and after (issue 6). See docs/diagnose.md, "Algorithm"."""

from omnibench.analysis.diagnosis.campaign import simulated_campaign  # noqa: F401
from omnibench.analysis.diagnosis.core import Diagnosis, diagnose, separating_experiment  # noqa: F401
