"""An independent Omnibot plant, written for testing only: diagnosis must hold on a world that
is not the model's own simulator.

It shares no numerical shortcut with `omnibench.model` (the fit's simulator):

- integrator: plain numpy vectorised over trajectories (no numba kernel, no RK4, no sub-step
  rule), fixed steps. Wheels in the air (H_UP = 0.5 ms): each step solved exactly for frozen
  drive and friction (exponential decay to the sliding speed, the zero crossing located inside
  the step). On the ground (H_GROUND = 0.5 ms): linearly implicit Euler on the body speeds;
  battery energy and winding heat by the trapezoid rule over each step;
- dry friction: upside down, exact Coulomb friction by time stepping (Moreau): a wheel whose
  momentum plus one step's impulse of every other torque is within the breakaway impulse
  h F_static stops dead, otherwise it slides with the exact sign; static friction is the sliding
  friction at zero speed (Stribeck: b + b_s). On the ground, linearly implicit Euler with a sign
  of width GROUND_SIGN_WIDTH (100 x sharper than the model's regularisation);
- effect forms written their own way: a deadband that cuts (`cut` 1: u below u_0 gives 0,
  above it passes unchanged, a hard edge) as well as the shifted one (`cut` 0), a Stribeck
  decay of any exponent (`shape`: 2 Gaussian, 1 exponential), asymmetric Coulomb friction that
  scales with the axle load like b, winding heating with its thermal time constant, a battery
  resistance that may grow with current (`k_i`, 1/A);
- command timing (command_latency, serial_command_latency, per_wheel_latency): each wheel
  holds the command issued last before t - its latency, sampled at the middle of each step
  (the model averages the delayed schedule over its step instead); actuator_lag: the seen duty
  relaxes exactly towards the (delayed) command over each step, the step driven by its mean;
- effects outside the library: `wheel_radius` (one wheel's rolling radius scaled), `bent_axle`
  (one wheel's friction varying once per revolution), `set_screw` (one wheel slips on its shaft
  above a torque: the encoder on the motor sees more speed than the wheel makes).

World effects use the library's names and parameter names (docs/effects.md) plus these
form parameters, so a test world reads the same either way. Outputs mirror
`omnibench.model.simulate_batch` (`IndependentResult.signal`), and `IndependentPlant` stands in
for `omnibench.sim.plant.Plant` behind the simulated board's serial path (`sim://?plant=independent`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from omnibench.model.context import GRAVITY
from omnibench.model.geometry import inverse_kinematics, slip_matrix, wheel_positions
from omnibench.model.scenario import Scenario, operator_change

H_UP = 5e-4  # s, the fixed step with the wheels in the air (exact between events)
H_GROUND = 5e-4  # s, the fixed step on the ground (linearly implicit Euler)
GROUND_SIGN_WIDTH = 1e-3  # rad/s for wheel speeds; / 10 in m/s for roller slip
OUT_OF_LIBRARY = ("wheel_radius", "bent_axle", "set_screw")


def _p(effects: Mapping[str, Mapping[str, float]], name: str, key: str, default: float = 0.0) -> float:
    return float(effects.get(name, {}).get(key, default))


@dataclass
class _World:
    """Per-trajectory constants (arrays over B), read once from robot and scenario."""

    up: np.ndarray  # (B,) bool
    FN: np.ndarray  # (B, 4) N
    mass: np.ndarray  # (B,) kg
    Rm: np.ndarray  # (B, 4, 3)
    Sm: np.ndarray  # (4, 3)
    M: np.ndarray  # (B, 3, 3)
    e: dict  # effect parameter arrays
    lag: np.ndarray  # (B, 4) s, each wheel's command latency (timing effects)


def _prepare(robot, scenarios: Sequence[Scenario]) -> _World:
    B = len(scenarios)
    s_pos, d_pos = wheel_positions(robot.L, robot.l)
    R0 = inverse_kinematics(robot.L, robot.l, robot.r, robot.alpha)
    Sm = slip_matrix(robot.L, robot.l, robot.alpha)
    up = np.array([sc.mode == "upside_down" for sc in scenarios])
    mass = np.array([robot.m + sc.payload for sc in scenarios])
    FN = np.zeros((B, 4))
    Rm = np.repeat(R0[None], B, axis=0)
    names = ("u_0", "form_u", "b_s", "w_s", "c_s", "shape", "db", "d_q", "A_c", "n_c", "phase", "R_b", "k_i",
             "I_q", "theta", "tau_th", "alpha_cu", "theta_s", "psi_s", "bend", "bend_wheel", "screw", "screw_wheel",
             "screw_slip", "tau_a")
    e = {k: np.zeros(B) for k in names}
    e["da"], e["dbw"] = np.zeros((B, 4)), np.zeros((B, 4))
    lag = np.zeros((B, 4))
    for b, sc in enumerate(scenarios):
        ef = {k: dict(v) for k, v in robot.effects.items()}
        ef.update({k: dict(v) for k, v in sc.effects.items()})
        if sc.mode == "upside_down":
            masses = sc.wheel_mass if sc.wheel_mass is not None else robot.wheel_mass
            FN[b] = np.asarray(masses, dtype=float) * GRAVITY
        else:
            W = mass[b] * GRAVITY
            dx, dy = _p(ef, "com_offset", "dx"), _p(ef, "com_offset", "dy")
            FN[b] = W / 4 * (1 + dx * s_pos / robot.L ** 2 + dy * d_pos / robot.l ** 2)
        if "wheel_radius" in ef:  # one wheel rolls on a radius `scale` times the others'
            j = int(_p(ef, "wheel_radius", "wheel", 1)) - 1
            Rm[b, j] = R0[j] / _p(ef, "wheel_radius", "scale", 1.0)
        e["u_0"][b], e["form_u"][b] = _p(ef, "driver_deadband", "u_0"), _p(ef, "driver_deadband", "cut")
        e["b_s"][b], e["w_s"][b] = _p(ef, "stribeck_friction", "b_s"), _p(ef, "stribeck_friction", "w_s", 1.0)
        e["c_s"][b], e["shape"][b] = _p(ef, "stribeck_friction", "c_s", 0.01), _p(ef, "stribeck_friction", "shape", 2.0)
        e["db"][b] = _p(ef, "asymmetric_coulomb", "db")
        e["d_q"][b] = _p(ef, "quadratic_drag", "d_q")
        e["A_c"][b], e["n_c"][b] = _p(ef, "cogging_torque", "A_c"), _p(ef, "cogging_torque", "n_c", 10.0)
        e["phase"][b] = _p(ef, "cogging_torque", "phase")
        e["R_b"][b], e["k_i"][b] = _p(ef, "battery_resistance", "R_b"), _p(ef, "battery_resistance", "k_i")
        e["I_q"][b] = _p(ef, "quiescent_current", "I_q")
        e["theta"][b], e["tau_th"][b] = _p(ef, "winding_heating", "theta"), _p(ef, "winding_heating", "tau_th", 20.0)
        e["alpha_cu"][b] = _p(ef, "winding_heating", "alpha_cu", 0.00393)
        e["theta_s"][b], e["psi_s"][b] = _p(ef, "floor_slope", "theta_s"), _p(ef, "floor_slope", "psi_s")
        e["bend"][b], e["bend_wheel"][b] = _p(ef, "bent_axle", "amplitude"), _p(ef, "bent_axle", "wheel", 1) - 1
        e["screw"][b], e["screw_wheel"][b] = _p(ef, "set_screw", "torque"), _p(ef, "set_screw", "wheel", 1) - 1
        e["screw_slip"][b] = _p(ef, "set_screw", "slip", 0.5)
        e["tau_a"][b] = _p(ef, "actuator_lag", "tau_a")
        for j in range(4):
            e["da"][b, j] = _p(ef, "per_wheel_friction", f"da_{j + 1}")
            e["dbw"][b, j] = _p(ef, "per_wheel_friction", f"db_{j + 1}")
        lag[b] = _latencies(ef, sc.command_order)
        if sc.command_delays is not None:  # the firmware's own send latency
            lag[b] += np.asarray(sc.command_delays, dtype=float)
    M = np.zeros((B, 3, 3))
    M[:, 0, 0] = M[:, 1, 1] = mass
    M[:, 2, 2] = robot.I_z
    M += robot.I_w * np.einsum("bji,bjk->bik", Rm, Rm)
    return _World(up, FN, mass, Rm, Sm, M, e, lag)


def _latencies(ef: Mapping[str, Mapping[str, float]], order: Sequence[int] | None) -> np.ndarray:
    """Each wheel's command latency (4,), s: command_latency tau, plus serial_command_latency
    tau + tau_packet x (the wheel's place in the send order), plus per_wheel_latency tau_k of
    the wheel's place k in the send order (firmware timing follows the order)."""
    order = list(order) if order is not None else [1, 2, 3, 4]
    out = np.full(4, _p(ef, "command_latency", "tau"))
    for j in range(4):
        out[j] += _p(ef, "serial_command_latency", "tau") + _p(ef, "serial_command_latency", "tau_packet") * order.index(j + 1)
        out[j] += _p(ef, "per_wheel_latency", f"tau_{order.index(j + 1) + 1}")
    return out


def _delayed(t_cmd: np.ndarray, U: np.ndarray, lag: np.ndarray, t: float) -> np.ndarray:
    """Duties (B, 4) acting at time t: wheel j of trajectory b holds the command issued last
    before t - lag[b, j] (zero-order hold sampled at t; 0 before the first)."""
    k = np.searchsorted(t_cmd, t - lag, side="right") - 1  # (B, 4)
    got = np.take_along_axis(U, np.maximum(k, 0)[:, None, :], axis=1)[:, 0, :]
    return np.where(k >= 0, got, 0.0)


class IndependentPhysics:
    """B trajectories of (robot, scenario) in lockstep; `step(u)` advances by `h` with duties u (B, 4)."""

    def __init__(self, robot, scenarios: Sequence[Scenario]) -> None:
        self.robot = robot
        self.scenarios = list(scenarios)
        self.w = _prepare(robot, self.scenarios)
        B = len(self.scenarios)
        self.t = 0.0
        self.q = np.zeros((B, 3))
        self.v = np.zeros((B, 3))
        self.phi = np.zeros((B, 4))  # encoder (motor side) angle
        self.wd = np.zeros((B, 4))  # wheel speeds upside down (motor side), rad/s
        self.dT = np.zeros((B, 4))  # winding temperature rise, K
        self.E_batt = np.zeros(B)
        self.i = np.zeros((B, 4))
        self.V = np.full(B, float(robot.V_batt))
        self.I_batt = np.zeros(B)
        self.slip = np.zeros((B, 4))  # set screw: wheel angle behind the motor, rad
        r, e, FN = robot, self.w.e, self.w.FN
        # constants of the run, and which effects are on anywhere (numpy's per-call overhead is
        # the cost here: what is off is not computed)
        self.on = {k: bool(np.any(e[v])) for k, v in (("strib", "b_s"), ("bend", "bend"), ("cog", "A_c"),
                                                        ("drag", "d_q"), ("Rb", "R_b"), ("heat", "theta"))}
        self.load = 1.0 + r.c * FN
        self.Fb = self.load * r.b + e["dbw"]
        self.asym = e["db"][:, None] * self.load
        self.strib_amp = (1.0 + e["c_s"][:, None] * FN) * e["b_s"][:, None]
        self.ws = np.maximum(e["w_s"], 1e-9)[:, None]
        self.d_lin = self.load * r.a + e["da"]
        self.G0 = np.full((B, 4), 1.0 / r.R_a)
        self.V0 = np.full(B, float(r.V_batt))
        self._u_last: tuple | None = None
        self.u_act = np.zeros((B, 4))  # actuator_lag: the duty the motors see (0 at the start)
        self.lagged = bool(np.any(e["tau_a"] > 0))
        self.screw = bool(np.any(e["screw"]))
        self.rolling = FN * r.C_r * r.r  # rolling resistance at the wheel, N m
        self.roller_load = 1.0 + r.c_r * FN
        self.I_idle = r.I_0 + e["I_q"]  # A
        self._dry_const = (self.Fb + self.asym, self.Fb - self.asym)
        self.Fs = self.w.mass * GRAVITY * np.sin(e["theta_s"])  # the floor slope's pull, N
        up = self.w.up
        # which trajectories each kind of step advances: all of them (most batches are of one
        # mode) without a masked copy per array and step
        self._any_up, self._any_ground = bool(up.any()), bool((~up).any())
        self._up_rows = slice(None) if up.all() else up
        self._ground_rows = slice(None) if not up.any() else ~up

    # ------------------------------------------------------------------ pieces
    def _duty(self, u: np.ndarray) -> np.ndarray:
        if self._u_last is not None and self._u_last[0] is u:
            return self._u_last[1]
        e = self.w.e
        u0 = e["u_0"][:, None]
        mag = np.abs(u)
        shifted = np.sign(u) * np.maximum(mag - u0, 0.0)
        cut = np.where(mag > u0, u, 0.0)
        out = np.clip(np.where(e["form_u"][:, None] > 0.5, cut, shifted), -1.0, 1.0)
        self._u_last = (u, out)
        return out

    def _electrical(self, u: np.ndarray, phid: np.ndarray):
        """Battery voltage (fixed point on V = V_oc - R_b(I) I) and winding conductances."""
        if not (self.on["Rb"] or self.on["heat"]):
            return self.V0, self.G0
        r, e = self.robot, self.w.e
        G = 1.0 / (r.R_a * (1.0 + e["alpha_cu"][:, None] * self.dT))
        if not self.on["Rb"]:
            return self.V0, G  # V_batt - 0 x I: the supply itself
        V = self.V.copy()
        for _ in range(6 if self.on["Rb"] else 1):
            i = (u * V[:, None] - r.k_e * phid) * G
            I = np.sum(u * i, axis=1) + r.I_0 + e["I_q"]
            V = r.V_batt - e["R_b"] * (1.0 + e["k_i"] * np.abs(I)) * I
        return V, G

    def _dry(self, w: np.ndarray | None):
        """(forward, backward) dry friction magnitudes at speed w (B, 4) (None: at rest, the
        breakaway friction), N m: the paper's b, the Stribeck hump (decay exponent `shape`),
        asymmetry scaling with the load like b, per-wheel differences, a bent axle."""
        if not (self.on["strib"] or self.on["bend"]):
            return self._dry_const
        F = self.Fb
        if self.on["strib"]:
            F = F + (self.strib_amp if w is None else
                     self.strib_amp * np.exp(-np.abs(w / self.ws) ** self.w.e["shape"][:, None]))
        if self.on["bend"]:
            e = self.w.e
            j = e["bend_wheel"].astype(int)
            rows = np.arange(len(j))
            F = F.copy()
            F[rows, j] += e["bend"] * self.load[rows, j] * self.robot.b * np.cos(self.phi[rows, j])
        return F + self.asym, F - self.asym

    # ------------------------------------------------------------------ steps
    @property
    def h(self) -> float:
        """The step, s: H_GROUND, or H_UP when any trajectory has its wheels in the air (those
        step at H_UP in any case)."""
        return H_UP if self.w.up.any() else H_GROUND

    def step(self, u_cmd: np.ndarray) -> None:
        """Advance every trajectory by `self.h` with duties u_cmd (B, 4) held."""
        u_cmd = np.asarray(u_cmd, dtype=float)
        if self.lagged:
            u_cmd = self._actuator(u_cmd)
        u = self._duty(u_cmd)
        for _ in range(int(round(self.h / H_UP)) if self._any_up else 0):
            self._step_up(u, self._up_rows)
        if self._any_ground:
            self._step_ground(u, self._ground_rows, self.h)
        self.t += self.h

    def _actuator(self, u_cmd: np.ndarray) -> np.ndarray:
        """actuator_lag, solved exactly for a command held over the step: the seen duty relaxes
        as u + (u0 - u) exp(-t / tau_a); the step is driven by its mean over the step (the model
        filters the schedule in its own way)."""
        tau = self.w.e["tau_a"][:, None]
        h = self.h
        on = tau > 0
        x = np.where(on, h / np.where(on, tau, 1.0), np.inf)
        decay = np.exp(-x)
        gap = self.u_act - u_cmd
        mean = u_cmd + gap * np.where(on, -np.expm1(-x) / np.where(on, x, 1.0), 0.0)
        self.u_act = u_cmd + gap * decay
        return mean

    def _step_up(self, u: np.ndarray, m: np.ndarray | slice) -> None:
        """One step H_UP of the wheels in the air, solved exactly for frozen drive and friction:
        I dw/dt = tau0 - d w - F sign(w) decays exponentially towards (tau0 -+ F) / d; a wheel
        that reaches zero inside the step sticks there if |tau0| is within the breakaway
        friction, else it reverses for the rest of the step."""
        r, e, h = self.robot, self.w.e, H_UP
        w = self.wd
        self._speed_start = w
        V, G = self._electrical(u, w)
        d = r.eta * r.k_t * r.k_e * G + self.d_lin
        tau0 = r.eta * r.k_t * u * V[:, None] * G
        if self.on["drag"]:
            tau0 = tau0 - e["d_q"][:, None] * np.abs(w) * w
        if self.on["cog"]:
            tau0 = tau0 - e["A_c"][:, None] * np.sin(e["n_c"][:, None] * self.phi + e["phase"][:, None])
        Fp, Fm = self._dry(w)
        Fp0, Fm0 = self._dry(None) if (self.on["strib"] or self.on["bend"]) else (Fp, Fm)
        a = d / r.I_w
        decay = np.exp(-a * h)
        fwd = (w > 0) | ((w == 0) & (tau0 > Fp0))
        bwd = (w < 0) | ((w == 0) & (tau0 < -Fm0))
        w_inf = np.where(fwd, (tau0 - Fp) / d, (tau0 + Fm) / d)
        w_end = w_inf + (w - w_inf) * decay
        crossed = (fwd & (w_end < 0)) | (bwd & (w_end > 0))
        if crossed.any():
            with np.errstate(divide="ignore", invalid="ignore"):
                t_c = np.where(crossed, np.log(np.abs((w - w_inf) / np.where(w_inf == 0, 1e-300, w_inf))) / a, h)
            rest = np.clip(h - t_c, 0.0, h)
            stick = (tau0 <= Fp0) & (tau0 >= -Fm0)
            w_rev = np.where(w_end < 0, (tau0 - Fp) / d, (tau0 + Fm) / d) * (1.0 - np.exp(-a * rest))
            w_new = np.where(fwd | bwd, np.where(crossed, np.where(stick, 0.0, w_rev), w_end), 0.0)
        else:  # most steps: no wheel reaches zero inside the step
            w_new = np.where(fwd | bwd, w_end, 0.0)
        self._book(m, u, V, G, w_new, w_new, h)
        self.phi[m] += (0.5 * h * (w + w_new))[m]
        self.wd[m] = w_new[m]

    def _step_ground(self, u: np.ndarray, m: np.ndarray | slice, h: float) -> None:
        """One linearly implicit Euler step on the body speeds (M - h dG/dv) dv = h G(v)."""
        r, e, Rm, Sm = self.robot, self.w.e, self.w.Rm, self.w.Sm
        v = self.v
        phid = np.einsum("bjk,bk->bj", Rm, v)
        self._speed_start = phid + self.slip_rate
        sig = v @ Sm.T
        V, G = self._electrical(u, phid)
        eps, eps_s = GROUND_SIGN_WIDTH, GROUND_SIGN_WIDTH / 10.0
        q, qs = phid ** 2 + eps ** 2, sig ** 2 + eps_s ** 2
        sg, dsg = phid / np.sqrt(q), eps ** 2 / q ** 1.5
        ss, dss = sig / np.sqrt(qs), eps_s ** 2 / qs ** 1.5
        Fp, Fm = self._dry(phid)
        dry = np.where(sg >= 0, Fp, Fm) + self.rolling
        load = self.load
        i = (u * V[:, None] - r.k_e * phid) * G
        # (an effect that is off everywhere is not computed: it would add zeros)
        tau = r.eta * r.k_t * i - self.d_lin * phid - dry * sg
        dtau = r.eta * r.k_t * r.k_e * G + load * r.a + e["da"] + dry * dsg
        if self.on["drag"]:
            tau = tau - e["d_q"][:, None] * np.abs(phid) * phid
            dtau = dtau + 2 * e["d_q"][:, None] * np.abs(phid)
        dtau = -dtau
        if self.on["cog"]:
            tau -= e["A_c"][:, None] * np.sin(e["n_c"][:, None] * self.phi + e["phase"][:, None])
        if self.screw:  # a set screw slips: the wheel transmits at most `torque`
            tau, dtau = self._set_screw(tau, dtau)
        lr = self.roller_load
        fr = -lr * (r.a_r * sig + r.b_r * ss)
        dfr = -lr * (r.a_r + r.b_r * dss)
        psi = self.q[:, 2]
        Fs = self.Fs
        pull = np.zeros_like(v)  # the slope's pull and the Coriolis term, body frame (no torque)
        pull[:, 0] = Fs * np.cos(e["psi_s"] - psi) + self.w.mass * v[:, 2] * v[:, 1]
        pull[:, 1] = Fs * np.sin(e["psi_s"] - psi) - self.w.mass * v[:, 2] * v[:, 0]
        g = np.einsum("bjk,bj->bk", Rm, tau) + fr @ Sm + pull
        J = np.einsum("bji,bj,bjk->bik", Rm, dtau, Rm) + np.einsum("ji,bj,jk->bik", Sm, dfr, Sm)
        dv = np.linalg.solve(self.w.M - h * J, h * g[:, :, None])[:, :, 0]
        v_new = v + dv
        phid_new = np.einsum("bjk,bk->bj", Rm, v_new)
        motor_speed = phid_new + self.slip_rate
        self._book(m, u, V, G, phid_new, motor_speed, h)
        c, s = np.cos(psi), np.sin(psi)
        vw = np.empty_like(v_new)
        vw[:, 0] = c * v_new[:, 0] - s * v_new[:, 1]
        vw[:, 1] = s * v_new[:, 0] + c * v_new[:, 1]
        vw[:, 2] = v_new[:, 2]
        self.q[m] += h * vw[m]
        self.v[m] = v_new[m]
        self.phi[m] += h * motor_speed[m]

    slip_rate: float | np.ndarray = 0.0  # (n, 4) rad/s once a screw slips

    def _set_screw(self, tau: np.ndarray, dtau: np.ndarray):
        """Wheel j's screw slips once its torque exceeds `torque`: the motor side spins ahead at
        `slip` x the excess (rad/s per N m), the wheel gets the limit."""
        e = self.w.e
        rows = np.arange(tau.shape[0])
        j = e["screw_wheel"].astype(int)
        lim = np.where(e["screw"] > 0, e["screw"], np.inf)
        t = tau[rows, j]
        excess = np.maximum(np.abs(t) - lim, 0.0)
        rate = np.zeros_like(tau)
        rate[rows, j] = np.sign(t) * excess * e["screw_slip"]
        self.slip_rate = rate
        tau = tau.copy()
        tau[rows, j] = np.clip(t, -lim, lim)
        return tau, dtau

    def _book(self, m, u, V, G, wheel_speed, motor_speed, h: float) -> None:
        """Currents at the end of the step; battery energy and winding heat by the trapezoid rule
        over the step (the start values are the last step's end values, at the step's duties)."""
        r, e = self.robot, self.w.e
        i = (u * V[:, None] - r.k_e * motor_speed) * G
        I = np.add.reduce(u * i, axis=1) + self.I_idle
        i_start = (u * V[:, None] - r.k_e * self._speed_start) * G
        I_start = np.add.reduce(u * i_start, axis=1) + self.I_idle
        self.E_batt[m] += (0.5 * h * V * (I + I_start))[m]
        if self.on["heat"]:
            i2 = 0.5 * (i ** 2 + i_start ** 2)
            heat = (e["theta"][:, None] * i2 * (1.0 + e["alpha_cu"][:, None] * self.dT) - self.dT) / np.maximum(
                e["tau_th"][:, None], 1e-9)
            self.dT[m] += h * np.where(e["theta"][:, None] > 0, heat, 0.0)[m]
        self.i[m], self.V[m], self.I_batt[m] = i[m], V[m], I[m]

    def currents(self, u_cmd: np.ndarray):
        """(motor currents (B, 4), V_batt, I_batt) at this instant under duties u_cmd: the current
        has no inductance here, so it jumps with a duty change; a sample taken at a switch reads
        the new duty's current."""
        r, e = self.robot, self.w.e
        u = self._duty(np.asarray(u_cmd, dtype=float))
        speed = self.phi_dot()
        V, G = self._electrical(u, speed)
        i = (u * V[:, None] - r.k_e * speed) * G
        return i, V, np.sum(u * i, axis=1) + (r.I_0 + e["I_q"])

    def phi_dot(self) -> np.ndarray:
        """Motor-side wheel speeds (what the encoders see), rad/s."""
        ground = np.einsum("bjk,bk->bj", self.w.Rm, self.v) + self.slip_rate
        return np.where(self.w.up[:, None], self.wd, ground)


SIGNALS = ("x", "y", "psi", "v1", "v2", "psi_dot", "phi1", "phi2", "phi3", "phi4", "phi_dot1", "phi_dot2",
           "phi_dot3", "phi_dot4", "i1", "i2", "i3", "i4", "V_batt", "I_batt", "E_batt")


@dataclass
class IndependentResult:
    """Recorded signals (B, n_rec) by name, like `omnibench.model.simulator.BatchResult.signal`."""

    t: np.ndarray
    data: dict

    def signal(self, name: str) -> np.ndarray:
        return self.data[name]


def _record(ph: IndependentPhysics, u_cmd: np.ndarray) -> dict:
    pd_ = ph.phi_dot()
    i, V, I = ph.currents(u_cmd)
    out = {"x": ph.q[:, 0], "y": ph.q[:, 1], "psi": ph.q[:, 2], "v1": ph.v[:, 0], "v2": ph.v[:, 1],
           "psi_dot": ph.v[:, 2], "V_batt": V, "I_batt": I, "E_batt": ph.E_batt}
    for j in range(4):
        out[f"phi{j + 1}"], out[f"phi_dot{j + 1}"], out[f"i{j + 1}"] = ph.phi[:, j], pd_[:, j], i[:, j]
    return {k: np.array(v, dtype=float) for k, v in out.items()}


def simulate_batch(robots, scenarios, t_cmd, u_cmd, t_end: float, *, dt: float = 1e-3,
                   record_every: int = 1, **_ignored) -> IndependentResult:
    """Drop-in for `omnibench.model.simulate_batch` (one robot; scenarios one per trajectory),
    recorded every `record_every` x `dt` s. Duties u_cmd (K, 4) shared or (B, K, 4)."""
    robot = robots if not isinstance(robots, (list, tuple)) else robots[0]
    scen = [scenarios] if isinstance(scenarios, Scenario) else list(scenarios)
    t_cmd = np.asarray(t_cmd, dtype=float)
    U = np.asarray(u_cmd, dtype=float).reshape(-1, len(t_cmd), 4)
    B = max(len(scen), U.shape[0])
    scen = scen * B if len(scen) == 1 else scen
    U = np.repeat(U, B, axis=0) if U.shape[0] == 1 else U
    ph = IndependentPhysics(robot, scen)
    per = max(1, int(round(dt / ph.h)))
    n_steps = int(round(t_end / dt))
    held: dict[int, np.ndarray] = {}  # one array per command: the deadband's duty is computed once per command

    def cmd(n: int) -> np.ndarray:
        k = int(np.searchsorted(t_cmd, n * dt + 1e-9, side="right")) - 1
        if k not in held:
            held[k] = U[:, k] if k >= 0 else np.zeros((B, 4))
        return held[k]

    u = cmd(0)
    recs = [_record(ph, u)]
    lagged = bool(np.any(ph.w.lag))
    for n in range(n_steps):
        for _ in range(per):
            # a latency: each wheel's held command sampled at the middle of the step, delayed
            ph.step(_delayed(t_cmd, U, ph.w.lag, ph.t + 0.5 * ph.h) if lagged else u)
        u_next = cmd(min(n + 1, n_steps - 1))
        if (n + 1) % record_every == 0:
            recs.append(_record(ph, u_next))
        u = u_next if u_next is not u else u
    t = np.arange(len(recs)) * record_every * dt
    return IndependentResult(t, {k: np.stack([r[k] for r in recs], axis=1) for k in recs[0]})


class IndependentPlant:
    """`omnibench.sim.plant.Plant` with the independent physics: the simulated board's plant
    when its world says `plant = "independent"`."""

    def __init__(self, robot, scenario: Scenario, dt: float = 1e-3) -> None:
        self.robot = robot
        self._scenario = scenario
        self.ph = IndependentPhysics(robot, [scenario])
        self._issued: list[tuple[float, np.ndarray]] = []  # (board time, duties) as commanded
        self.state = self._state()

    @property
    def scenario(self) -> Scenario:
        return self._scenario

    def _state(self):
        from omnibench.model.simulator import SimState

        ph = self.ph
        return SimState(t=ph.t, pose=ph.q[0].copy(), velocity=ph.v[0].copy(), phi=ph.phi[0].copy(),
                        phi_dot=ph.phi_dot()[0].copy(), motor_current=ph.i[0].copy(), V_batt=float(ph.V[0]),
                        I_batt=float(ph.I_batt[0]), E_batt=float(ph.E_batt[0]))

    def advance_to(self, t: float, duties: np.ndarray) -> None:
        """Integrate up to board time `t` (s) holding `duties`."""
        u = np.asarray(duties, dtype=float)[None]
        lag = self.ph.w.lag
        if np.any(lag):  # the board's commands, as issued, reach the wheels late
            if not self._issued or not np.array_equal(self._issued[-1][1], u[0]):
                self._issued.append((self.ph.t, u[0].copy()))
            t_cmd = np.array([h[0] for h in self._issued])
            U = np.array([h[1] for h in self._issued])[None]
        while self.ph.t + 0.5 * self.ph.h <= t:
            self.ph.step(_delayed(t_cmd, U, lag, self.ph.t + 0.5 * self.ph.h) if np.any(lag) else u)
        self.state = self._state()

    def set_world(self, mode: str | None = None, payload: float | None = None,
                  wheel_mass: tuple[float, float, float, float] | None = None) -> None:
        """Operator action with the robot at rest: a new world, same time, energy and angles."""
        old = self.ph
        self._scenario = operator_change(self._scenario, mode, payload, wheel_mass)
        self.ph = IndependentPhysics(self.robot, [self._scenario])
        self.ph.t, self.ph.phi, self.ph.E_batt, self.ph.dT = old.t, old.phi.copy(), old.E_batt.copy(), old.dT.copy()
        self.ph.u_act = old.u_act.copy()
        self.state = self._state()

    def at_rest(self, tol: float = 1e-3) -> bool:
        """True if every wheel turns slower than `tol` rad/s."""
        return bool(np.all(np.abs(self.state.phi_dot) < tol))
