"""Analysis: fit, validate-energy, predict (and the diagnosis built on them).

Reads run files (through omnibench.runs), never the port. The estimators see `Observations`
(omnibench.analysis.observations), not run directories.

    from omnibench.analysis import Observations, fit, FitResult
    obs = Observations.from_runs(["runs/"])          # or simcampaign.simulated_observations(robot, seed=1)
    result = fit(robot, obs)                           # free=None: what the procedures measure
    print(result.table())
"""

from omnibench.analysis.fitting import (
    FitResult,
    Verdict,
    default_free,
    error_by_procedure,
    fit,
    fit_per_wheel,
    predict_observations,
    sweep_linear_estimate,
)
from omnibench.analysis.least_squares import with_params
from omnibench.analysis.observations import Observations

__all__ = ["FitResult", "Observations", "Verdict", "default_free", "error_by_procedure", "fit", "fit_per_wheel",
           "predict_observations", "sweep_linear_estimate", "with_params"]
