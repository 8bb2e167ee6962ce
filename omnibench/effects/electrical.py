"""Electrical effects (`electrical` hook, and own states for the winding temperature).

  battery_resistance   V = (V_oc - R_b I_batt)            series resistance of the pack and wiring
  quiescent_current    I_batt += I_q                       electronics drawn from the battery
  winding_heating      R_a,i -> R_a (1 + alpha_cu dT_i),   d(dT_i)/dt = (theta i_i^2 (1 + alpha_cu dT_i) - dT_i) / tau_th

The kernel solves the motor currents and the terminal voltage together, in closed form, with
the series resistance (see `omnibench.model.kernel`).
"""

from __future__ import annotations

from numba import njit

from omnibench.model.context import ELEC_I_Q, ELEC_R_BATT, ELEC_RA_SCALE
from omnibench.model.terms import Param, Term, register


@njit(cache=True)
def battery_resistance_elec(elec, xs, ctx, p):
    """Add the pack's internal resistance R_b (ohm) in series with the supply."""
    elec[ELEC_R_BATT] += p[0]


@njit(cache=True)
def quiescent_current_elec(elec, xs, ctx, p):
    """Add the electronics' quiescent current I_q (A) to the battery current."""
    elec[ELEC_I_Q] += p[0]


@njit(cache=True)
def winding_heating_elec(elec, xs, ctx, p):
    """Scale each motor's winding resistance by 1 + alpha_cu dT (copper)."""
    alpha = p[2]
    for j in range(4):
        elec[ELEC_RA_SCALE + j] *= 1.0 + alpha * xs[j]


@njit(cache=True)
def winding_heating_rate(dxs, xs, i_motor, phi_dot, elec, ctx, p):
    """d(dT)/dt = (theta i^2 R_scale - dT) / tau_th, K/s; theta = R_a R_th (K/A^2)."""
    theta, tau_th = p[0], p[1]
    if theta == 0.0:
        return
    for j in range(4):
        dxs[j] = (theta * i_motor[j] * i_motor[j] * elec[ELEC_RA_SCALE + j] - xs[j]) / tau_th


battery_resistance = register(
    Term(
        name="battery_resistance",
        title="Battery internal resistance",
        doc="V_batt = V_oc - R_b I_batt: the pack and its wiring sag under load. Start-up "
        "currents of four motors (tens of amperes) make it visible in step responses; in the "
        "energy test it lowers both the power and the speed reached.",
        params=(Param("R_b", "ohm", 0.15, "series resistance of battery and wiring", 0.0, 5.0),),
        hooks={"electrical": battery_resistance_elec},
        reveals="step_response (slower start from high duty), energy_trajectories, upside_down_sweep (high duties)",
    )
)

quiescent_current = register(
    Term(
        name="quiescent_current",
        title="Quiescent electronics current",
        doc="I_batt = sum(u_i i_i) + I_0 + I_q: board, drivers and encoders draw current whether "
        "or not the wheels turn. Invisible in the mechanics; the energy test shows it as energy "
        "that grows with duration, not distance.",
        params=(Param("I_q", "A", 0.15, "extra current drawn by the electronics", 0.0, 5.0),),
        hooks={"electrical": quiescent_current_elec},
        reveals="energy_trajectories (excess energy proportional to duration)",
    )
)

winding_heating = register(
    Term(
        name="winding_heating",
        title="Winding heating (copper resistance rises with temperature)",
        doc="R_a,i = R_a (1 + alpha_cu dT_i), first-order thermal model per motor: "
        "tau_th d(dT)/dt = theta i^2 (1 + alpha_cu dT) - dT with theta = R_a R_th the steady "
        "temperature rise per squared ampere. A warm motor is weaker at the same duty: steady "
        "speeds drift down over a campaign.",
        params=(
            Param("theta", "K/A^2", 15.0, "steady winding temperature rise per A^2 (R_a R_th)", 0.0, 200.0),
            Param("tau_th", "s", 60.0, "thermal time constant of the winding", 1.0, 1e5),
            Param("alpha_cu", "1/K", 0.00393, "temperature coefficient of copper resistance", 0.0, 0.01),
        ),
        hooks={"electrical": winding_heating_elec, "state_derivative": winding_heating_rate},
        n_states=4,
        state_init=(0.0, 0.0, 0.0, 0.0),
        reveals="upside_down_sweep and step_response (residual drifts with time, grows with current)",
    )
)
