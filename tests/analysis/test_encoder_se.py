"""Standard errors that know the encoder's rounding (diagnosis/encoder_se.py) against Monte Carlo
over the mounting phase, and the latency fit's difference step (least_squares.fd_steps)."""

import math
from types import SimpleNamespace

import numpy as np
import pandas as pd

from omnibench.analysis.diagnosis.encoder_se import encoder_se, sawtooth_cov

CPR = 980.0
K = CPR / (2 * math.pi)  # counts per rad


def test_sawtooth_covariance_matches_monte_carlo_over_the_phase():
    rng = np.random.default_rng(1)
    off = rng.uniform(0, 1, 200_000)
    e = lambda x: np.floor(x + off) - x - off  # noqa: E731  (the mounting offset itself cancels in speeds)
    for d in (0.0, 0.25, 0.5, 3.8):
        mc = np.cov(e(0.3), e(0.3 + d))[0, 1]
        assert abs(mc - sawtooth_cov(np.array(d))) < 2e-3
    # a difference known only to +- sigma: the Fourier terms are averaged over it
    jitter = rng.normal(0, 0.3, off.size)
    mc = np.cov(e(0.3), e(0.3 + 0.5 + jitter))[0, 1]
    assert abs(mc - sawtooth_cov(np.array(0.5), 0.3)) < 2e-3
    assert abs(sawtooth_cov(np.array(0.5), 0.3)) < 0.3 * abs(sawtooth_cov(np.array(0.5)))  # mostly decorrelated


def _square_orbit(t, amplitude=1.0):
    """A wheel angle (rad) under a square wave of duties reversing every 0.25 s: speed
    +-10 rad/s approached with a 30 ms time constant, scaled by `amplitude` (periodic)."""
    tau_m, half, w_max = 0.03, 0.25, 10.0 * amplitude
    t = np.asarray(t, dtype=float)
    k = np.floor(t / half)
    s = t - k * half  # time since the last reversal
    sign = np.where(k % 2 == 0, 1.0, -1.0)
    w0 = -w_max * math.tanh(half / (2 * tau_m))  # speed at each reversal of the periodic orbit
    travel = lambda x: w_max * x + (w0 - w_max) * tau_m * (1 - np.exp(-x / tau_m))  # noqa: E731
    return np.where(k % 2 == 0, 0.0, travel(half)) + sign * travel(s)


def _problem(ts, y, f):
    """The bits of an engine.Problem that encoder_se reads: one step-response run, one wheel."""
    n = len(ts) - 1
    table = pd.DataFrame({"procedure": "step_response", "signal": "omega", "run": "r", "wheel": 1,
                          "time": 0.5 * (ts[1:] + ts[:-1]), "u": np.sign(np.sin(2 * math.pi * (ts[1:] + ts[:-1]) / 2 / 0.5))})
    obs = SimpleNamespace(runs={"r": {"counts_per_rev": CPR}}, traces={("r", 0): pd.DataFrame({"t": ts})})
    return SimpleNamespace(table=table, used=np.ones(n, dtype=bool), obs=obs, y=y)


def _trial(rng):
    """One logged square-wave-like run (20 +- 5 ms samples, every turn-round logged) of an orbit
    placed at random on the count grid: (z = fitted shift / encoder SE, fitted shift / textbook SE)."""
    ts = [0.0]
    while ts[-1] < 4.0:
        ts.append(ts[-1] + 0.02 + rng.uniform(-0.005, 0.005))
    ts = np.unique(np.round(np.concatenate([ts, np.arange(0, 4.0, 0.25)]), 3))
    dt = np.diff(ts)
    amp = 1.0 + rng.uniform(0, 2) / K / 2.2  # the orbit's place on the count grid, to a count or two
    h = 1e-5
    f = np.diff(_square_orbit(ts, amp)) / dt  # speeds predicted at the true shift 0
    J = (np.diff(_square_orbit(ts + h, amp)) - np.diff(_square_orbit(ts - h, amp))) / (2 * h) / dt  # d f / d tau
    y = np.diff(np.floor(_square_orbit(ts, amp) * K + rng.uniform()) / K) / dt
    tau = np.dot(J, y - f) / np.dot(J, J)  # least-squares shift
    s = np.sqrt(np.mean((y - f) ** 2))  # profiled scale
    w = np.full(len(f), 1 / s)
    textbook = 1 / math.sqrt(np.sum((J * w) ** 2))
    se = encoder_se(_problem(ts, y, f), f, (J * w)[:, None], w)[0]
    return tau / se, tau / textbook


def test_periodic_revisits_widen_the_se_to_the_spread_of_the_fit():
    """A time shift of a periodic orbit fitted to finite-difference speeds of rounded angles:
    the samples at each turn-round repeat their rounding error every cycle, so the textbook SE
    is some 3x too small; over the encoder-aware SE the fitted shifts spread about 1.2-1.3
    (angles a few counts apart keep part of their correlation, which the SE averages over the
    trajectory's uncertainty), so 3 SE covers them."""
    rng = np.random.default_rng(3)
    z, z_textbook = np.array([_trial(rng) for _ in range(60)]).T
    assert np.std(z_textbook) > 2.0  # the rounding errors of revisited angles do not average out
    assert 0.8 < np.std(z) < 1.5
    assert np.all(np.abs(z) < 3.5)


def test_a_latency_fit_steps_over_the_simulators_crossing_jumps(omnibot):
    """The model's prediction jumps each time a reversal's zero crossing moves to the next
    physics step; a latency differenced over microseconds stopped on such a jump (19.55 ms
    +- 7 us for a world's 20 ms, seed 1004). Differenced over one physics step (least_squares.fd_steps)
    the fit reaches the truth within 3 SE from the same start."""
    from omnibench.analysis.diagnosis import engine
    from omnibench.analysis.diagnosis.campaign import REVEALING, campaign
    from omnibench.effects import EFFECTS

    eff = EFFECTS["command_latency"]
    obs = campaign(omnibot, REVEALING["command_latency"], eff.world(), seed=1004, generator="independent")
    problem = engine.Problem(obs, obs.procedures())
    start = engine._robot_with_effect(omnibot, eff, {"tau": 0.005})
    fit = engine.fit_model(problem, start, ["command_latency.tau"], max_nfev=15, passes=2)
    tau, se = fit.values["command_latency.tau"], fit.se["command_latency.tau"]
    assert abs(tau - 0.02) < 3 * se
    assert se < 2e-4  # and still a measurement: 0.2 ms on a 20 ms latency


def test_the_transient_test_does_not_count_a_shared_rounding_error_as_structure(omnibot):
    """With the right latency fitted, the first interval after every duty change of one sign
    starts at the same angle, so its rounding error repeats (~0.16 rad/s, seed 1002): counted as
    independent samples that is a 'latency structure' at p ~ 1e-5 that refused the right
    effect. Widened by the shared rounding, nothing significant is left."""
    from omnibench.analysis.diagnosis import engine, structure, transient
    from omnibench.analysis.diagnosis.campaign import REVEALING, campaign
    from omnibench.effects import EFFECTS

    eff = EFFECTS["command_latency"]
    obs = campaign(omnibot, REVEALING["command_latency"], eff.world(), seed=1002, generator="independent")
    problem = engine.Problem(obs, obs.procedures())
    fit = engine.fit_model(problem, engine._robot_with_effect(omnibot, eff, {"tau": 0.02}), ["command_latency.tau"],
                           max_nfev=10, passes=2)
    r = fit.residual(problem)
    w = fit.weights(problem)
    args = (problem.table, r, r * w, problem.used, problem.group)
    naive = transient.findings(*args)
    honest = transient.findings(*args, problem=problem, f=fit.f, w=w)
    n_tests = 20  # about as many as diagnose runs on a step-response campaign
    assert structure.significant(naive, n_tests)
    assert not structure.significant(honest, n_tests)
