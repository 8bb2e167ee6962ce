"""Candidate physical effects (docs/effects.md) as model terms.

Importing this package registers every effect with `omnibench.model.terms`, so the generated
kernel can simulate any of them and a robot file may declare them under [effects.<name>].
`omnibench.effects.library` describes each one for diagnosis (which parameters to fit, a
realistic size, the experiment that reveals it). docs/effects.md has the equations.
"""

from omnibench.effects import driver, electrical, environment, friction_extra, load, timing  # noqa: F401
from omnibench.effects.library import EFFECTS, Effect, effect_names  # noqa: F401

EFFECTS.update(timing.library_effects())  # command timing (effects/timing.py)
