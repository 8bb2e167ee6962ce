"""The integrator kernel, generated from the registry of terms and compiled once by numba.

Generation keeps the integrator ignorant of which effects exist: every registered term is
called through its hooks when it is enabled for a trajectory. The generated source is written
to a cache folder keyed by a hash of the terms' code, so numba's on-disk cache survives across
processes and the compile (about 35 s of CPU with the effects library) happens once per
machine and code version.

How it is made fast (issue 2; `benchmarks/simulate.py` measures it):
  - trajectories are integrated in groups of WIDTH lanes in lockstep, stored as structure of
    arrays (element i of lane k at i * WIDTH + k): each arithmetic instruction works on several
    trajectories at once (WIDTH 8: two AVX2 registers of four doubles). Hooks are written for
    one trajectory and are rewritten into lane form from their own source (`omnibench.model.lanes`); so is each
    section of the derivative below. Lanes of a group share sub-steps, mode and the set of
    enabled terms (those decide branches); a short group is padded with copies of its first
    lane. A trajectory's numbers do not depend on its batch up to rounding: the compiler may
    fuse a multiply-add differently in another lane (~1e-14 relative, tested);
  - every hook is compiled with numba `inline="always"` and the derivative is written straight
    into the stage loop: no call, no reference count, nothing allocated per step;
  - groups with every effect off run a lean copy of the loop generated without the effects'
    code (inlined but switched-off effects still cost the hot loop ~20 %);
  - every lane array is a flat view at a constant offset of one scratch buffer, so LLVM knows
    they never overlap and the index arithmetic is constant (numba's reshaped views carry
    their shape at run time, which defeats the vectoriser);
  - error_model="numpy" (no zero-division branches) and fastmath={"contract"} (fused
    multiply-add only: results move by ~1e-16 relative, nothing else is relaxed);
  - groups are spread over the cores with prange; libm sincos only when the heading has turned
    0.05 rad (else a Taylor rotation).

State vector X (per trajectory), all SI:
  0-2 pose q = (x, y, psi) in the world frame
  3-5 body velocity v = (v1, v2, psi_dot)
  6-9 wheel angles phi (rad)
  10-13 wheel speeds when upside down (on the ground phi_dot = R v)
  14 E_batt: battery energy delivered, integral of V_batt I_batt, J
  15 E_copper: integral of sum i^2 R_a, J
  16 E_conversion: integral of sum (k_e - eta k_t) i phi_dot (gear loss and constant mismatch), J
  17 E_quiescent: integral of V_batt I_q, J
  18.. E_term[k]: energy dissipated by term k (minus the integral of its power), J
  then every term's own states.
"""

from __future__ import annotations

import hashlib
import importlib.util
import inspect
import logging
import os
import sys
import tempfile
import textwrap
from pathlib import Path

from omnibench.locks import waiting_lock
from omnibench.model import context, fpu, lanes  # noqa: F401  (fpu: the generated kernel imports it)
from omnibench.model.terms import HOOKS, Layout, layout
from omnibench.resources import cache_root

# Robot vector rv: per-trajectory constants.
RV_NAMES = (
    "mode", "mass", "I_w", "k_t", "k_e", "R_a", "eta", "V_batt", "I_0", "L", "l", "r",
    "sign_width_phi", "sign_width_sigma", "W", "FN1", "FN2", "FN3", "FN4",
    "lam_base", "lam_phi", "lam_sigma",
)
RV = {name: k for k, name in enumerate(RV_NAMES)}
NX_FIXED = 18
X_Q, X_V, X_PHI, X_PHID = 0, 3, 6, 10
X_E_BATT, X_E_COPPER, X_E_CONV, X_E_QUIESCENT = 14, 15, 16, 17
# Auxiliary signals recorded beside the state.
AUX_NAMES = (
    "i1", "i2", "i3", "i4", "V_batt", "I_batt", "u1_eff", "u2_eff", "u3_eff", "u4_eff",
    "FN1", "FN2", "FN3", "FN4", "KE",
)
NAUX = len(AUX_NAMES)

METHOD_HEUN, METHOD_RK4 = 0, 1
# Stick-slip upside down (each wheel is its own degree of freedom there). The Coulomb-type
# terms see an exact sign (width EXACT_SIGN_WIDTH, far below any speed that matters), so a
# slipping wheel feels its full dry friction at every speed, and sticking is a state the step
# decides: a wheel whose speed reaches or crosses zero within a step is probed at
# +/- STICK_PROBE with every other quantity as at the end of the step; if both accelerations
# point back to zero (the drive does not overcome the breakaway torque, Filippov's sliding
# condition), the wheel is stuck: its speed is set to exactly 0 and the kinetic energy removed
# is booked as dissipated by the transmission friction, and its angle is that at the start of
# the step. Otherwise it breaks away (or reverses).
EXACT_SIGN_WIDTH = 1e-9  # rad/s
STICK_PROBE = 1e-6  # rad/s
# Adaptive sub-steps on the ground (issue 34). The sub-step count that keeps an explicit step
# stable is set by the largest decay rate of the speeds, and on the ground that rate comes from
# the regularised signs' slope at zero speed (1/eps: wheel_sign, slip_sign). Away from zero the
# slope falls (tanh: sech^2(x/eps); algebraic: (1 + (x/eps)^2)^-1.5), so a step whose speeds all
# stay clear of zero is stable with fewer sub-steps. rv's lam_base, lam_phi, lam_sigma split the
# rate at rest (stiffness.ground_split): the part that is not the signs', the wheel signs' part
# and the roller signs' part; each physics step then takes, per trajectory, the fewest sub-steps
# n with h lambda <= ADAPT_LIMITS[method] for
#     lambda = lam_base + lam_phi max_j s_phi(phi_dot_j) + lam_sigma max_j s_sigma(sigma_j),
# the slopes taken at each speed brought ADAPT_MARGIN x its change over the previous step closer
# to zero (never more than the fixed count SUB). After the step the same bound is checked on the
# speeds at its end (brought closer to zero by the step's own change; a speed that reached or
# crossed zero counts at full slope); a trajectory that fails is stepped again from the saved
# state with SUB sub-steps. Each trajectory chooses for itself (lanes of a group that need fewer
# sub-steps are held still for the rest of the group's sub-steps), so its numbers still do not
# depend on its batch. lam_phi = lam_sigma = 0 (the default) is the fixed count, bit for bit.
ADAPT_LIMITS = {METHOD_HEUN: 1.8, METHOD_RK4: 2.5}
ADAPT_MARGIN = 2.0
# Trajectories per lane group. Eight, not the four doubles of one AVX2 register: each operation
# then issues two independent vector instructions the core overlaps (issue 34, `omnibench fit` on
# a clean campaign's runs, one thread: the fit's CPU 3.78 -> 3.03 s, the per-wheel fits 0.77 ->
# 0.56 s with the host's code, 3.3 -> 2.8 s with AVX2-only code (NUMBA_CPU_NAME=haswell); the
# model file the same, bit for bit). OMNIBENCH_KERNEL_WIDTH=1 gives the plain form (one
# trajectory per group, hooks as written): benchmarks/simulate.py --compare-width measures what
# the lane form buys.
WIDTH = int(os.environ.get("OMNIBENCH_KERNEL_WIDTH", "8"))
if WIDTH not in (1, 2, 4, 8):
    raise ValueError(f"OMNIBENCH_KERNEL_WIDTH={WIDTH}: use 1, 2, 4 or 8")


def alias_name(k: int, hook: str) -> str:
    """Name of term k's hook (lane form) in the generated module."""
    return f"h{k}_{hook}"


def _indent(text: str, n: int) -> str:
    return textwrap.indent(text, " " * n)


def _source(lay: Layout, width: int = WIDTH) -> str:
    """Python source of the kernel module for this layout, `width` lanes per group."""
    C, rv, W = context, RV, width
    nt = len(lay.terms)
    if nt > 62:
        raise ValueError(f"{nt} registered terms: the kernel's lane grouping packs one bit per term into 62")
    nx = NX_FIXED + nt + lay.n_states
    # per-lane arrays (name, elements per lane): each a flat view of the scratch buffer
    slots: list[tuple[str, int]] = [
        ("X", nx), ("Xt", nx), ("dX", nx), ("acc", nx), ("aux", NAUX), ("rv", len(RV_NAMES)),
        ("Rm", 12), ("Sm", 12), ("Minv", 9), ("Mb", 9), ("ctx", C.CTX_SIZE), ("elec", C.ELEC_SIZE),
        ("FN", 4), ("u", 4), ("ucmd", 4), ("phid", 4), ("sig", 4), ("tau", 4), ("fr", 4), ("cur", 4),
        ("tmp", 4), ("gw", 4), ("w0", 4), ("a0", 4), ("chk", 4), ("hold", 4), ("acc_p", 4), ("fb", 3), ("tmp3", 3), ("psr", 1), ("cref", 1), ("sref", 1), ("Vb", 1), ("Ib", 1),
        ("hl", 1), ("hs", 1), ("tb", 1), ("tl", 1), ("nk", 1), ("pspd", 8), ("Xs", nx),
        ("xs_none", 0),
    ]
    for k, term in enumerate(lay.terms):
        slots.append((f"p{k}", len(term.params)))
        if term.n_states:
            slots += [(f"xs{k}", term.n_states), (f"dxs{k}", term.n_states)]
    arrays = {name for name, _ in slots} | {"q", "v", "phi"}

    def L(code: str, uses_lane: bool = False) -> str:
        """Per-trajectory code -> its loop over the lanes (`lanes.lane_block`)."""
        return lanes.lane_block(textwrap.dedent(code).strip("\n"), arrays, W, uses_lane=uses_lane)

    hook_defs: list[str] = []
    hook_imports: set[str] = set()
    modules: dict[str, int] = {}  # hook module -> its number in the hooks' global names
    # per-term pieces, each tagged with whether it belongs to one of the paper's terms
    calls: dict[str, list[tuple[bool, str]]] = {h: [] for h in HOOKS}
    p_fill: list[str] = []
    s_load: list[tuple[bool, str]] = []
    s_store: list[tuple[bool, str]] = []
    for k, term in enumerate(lay.terms):
        p0 = lay.param_offset[k]
        s0 = NX_FIXED + nt + lay.state_offset[k]
        ns = term.n_states
        p = f"p{k}"
        p_fill.append(f"for i in range({len(term.params)}):\n    {p}[i] = P[b, {p0} + i]")
        for hook, fn in term.hooks.items():
            home = getattr(fn, "py_func", fn).__module__
            number = modules.setdefault(home, len(modules))
            src, needed = lanes.lane_function(fn, alias_name(k, hook), W, prefix=f"m{number}_")
            hook_imports.update(lanes.import_line(alias, obj, name, home) for alias, (obj, name) in needed.items())
            hook_defs.append('@njit(inline="always", error_model="numpy", fastmath={"contract"})\n' + src)
        xs = f"xs{k}" if ns else "xs_none"
        if ns:
            s_load.append((term.core, L(f"for i in range({ns}):\n    {xs}[i] = Xt[{s0} + i]")))
        # the paper's terms are always on (prepare enables them for every trajectory): no
        # branch, so LLVM can share their common work (the regularised sign of the wheel speeds)
        en = "True" if term.core else f"EN[{k}] != 0.0"
        lanes_loop = f"for k in range({W}):"
        for hook in term.hooks:
            a = alias_name(k, hook)
            if hook == "normal_force":
                calls[hook].append((term.core, f"if {en}:\n    {lanes_loop}\n        {a}(FN, ctx, {p}, k)"))
            elif hook == "duty":
                calls[hook].append((term.core, f"if {en}:\n    {lanes_loop}\n        {a}(u, ctx, {p}, k)"))
            elif hook == "electrical":
                calls[hook].append((term.core, f"if {en}:\n    {lanes_loop}\n        {a}(elec, {xs}, ctx, {p}, k)"))
            elif hook in ("wheel_torque", "roller_force", "body_force"):
                n, out, speed, total, cond, args = {
                    "wheel_torque": (4, "tmp", "phid", "tau", en, f"tmp, phi, phid, FN, cur, {xs}, ctx, {p}"),
                    "roller_force": (4, "tmp", "sig", "fr", f"{en} and ground", f"tmp, sig, FN, ctx, {p}"),
                    "body_force": (3, "tmp3", "v", "fb", f"{en} and ground", f"tmp3, q, v, ctx, {p}"),
                }[hook]
                book = L(f"""
                    pw = 0.0
                    for j in range({n}):
                        {total}[j] += {out}[j]
                        pw += {out}[j] * {speed}[j]
                    dX[{NX_FIXED + k}] -= pw
                """)
                calls[hook].append((term.core,
                    f"if {cond}:\n    for i in range({n * W}):\n        {out}[i] = 0.0\n"
                    f"    {lanes_loop}\n        {a}({args}, k)\n" + _indent(book, 4)))
        if ns:
            zero = L(f"for i in range({ns}):\n    dX[{s0} + i] = 0.0")
            if "state_derivative" in term.hooks:
                a = alias_name(k, "state_derivative")
                copy = L(f"for i in range({ns}):\n    dX[{s0} + i] = dxs{k}[i]")
                s_store.append((term.core,
                    f"if {en}:\n    for i in range({ns * W}):\n        dxs{k}[i] = 0.0\n"
                    f"    {lanes_loop}\n        {a}(dxs{k}, {xs}, cur, phid, elec, ctx, {p}, k)\n"
                    + _indent(copy, 4) + "\nelse:\n" + _indent(zero, 4)))
            else:
                s_store.append((term.core, zero))

    def derivative(paper_only: bool) -> str:
        """The derivative's code; paper_only: without any effect's code (groups with every
        effect off run this lean copy: the hot loop stays small and fast)."""
        keep = lambda pieces: [text for core, text in pieces if core or not paper_only]  # noqa: E731
        body = {h: "\n".join(keep(c)) for h, c in calls.items()}
        text = _derivative(body, keep(s_load), keep(s_store), paper_only)
        return "\n".join(line for line in text.splitlines() if line.strip())

    def _derivative(body: dict[str, str], s_load: list[str], s_store: list[str], paper_only: bool) -> str:
        return "\n".join([
        "# ---- derivative dX = f(Xt, ucmd, ts) of every lane; aux gets the auxiliary signals ----",
        L(f"""
            ctx[{C.CTX_T}] = tl[0]
            ctx[{C.CTX_PSI}] = Xt[2]
            for j in range(3):
                fb[j] = 0.0
            for j in range(4):
                FN[j] = rv[{rv["FN1"]} + j]
                u[j] = ucmd[j]
                fr[j] = 0.0
            for i in range({nt}):
                dX[{NX_FIXED} + i] = 0.0
        """),
        *s_load,
        "# wheel speeds and roller slip speeds",
        "if ground:",
        _indent(L("""
            for j in range(4):
                phid[j] = Rm[3 * j] * Xt[3] + Rm[3 * j + 1] * Xt[4] + Rm[3 * j + 2] * Xt[5]
                sig[j] = Sm[3 * j] * Xt[3] + Sm[3 * j + 1] * Xt[4] + Sm[3 * j + 2] * Xt[5]
        """), 4),
        "else:",
        _indent(L("""
            for j in range(4):
                phid[j] = Xt[10 + j]
                sig[j] = 0.0
        """), 4),
        "# normal forces",
        body["normal_force"],
        "# duty map",
        body["duty"],
        L(f"""
            for j in range(4):
                u[j] = min(1.0, max(-1.0, u[j]))
            elec[{C.ELEC_R_BATT}] = 0.0
            elec[{C.ELEC_I_Q}] = rv[{rv["I_0"]}]
            for j in range(4):
                elec[{C.ELEC_RA_SCALE} + j] = 1.0
        """),
        "# electrical slots, then motor currents and battery voltage (closed form with the",
        "# battery's series resistance R_b; R_b = 0 gives V = V_oc exactly)",
        body["electrical"],
        L(f"""
            k_e = rv[{rv["k_e"]}]
            k_t = rv[{rv["k_t"]}]
            eta = rv[{rv["eta"]}]
            R_a = rv[{rv["R_a"]}]
            I_q = elec[{C.ELEC_I_Q}]
        """ + (f"""
            # the paper's terms only: no battery resistance and every winding at R_a, so the
            # general solution below reduces exactly to V = V_oc and one conductance 1 / R_a
            V = rv[{rv["V_batt"]}]
            G = 1.0 / R_a
            for j in range(4):
                gw[j] = G
        """ if paper_only else f"""
            R_b = elec[{C.ELEC_R_BATT}]
            num = rv[{rv["V_batt"]}] - R_b * I_q
            den = 1.0
            for j in range(4):
                G = 1.0 / (R_a * elec[{C.ELEC_RA_SCALE} + j])  # winding conductance, S
                gw[j] = G
                num += R_b * u[j] * k_e * phid[j] * G
                den += R_b * u[j] * u[j] * G
            V = num / den
        """) + f"""
            I_batt = I_q
            copper = 0.0
            conv = 0.0
            for j in range(4):
                c = (u[j] * V - k_e * phid[j]) * gw[j]
                cur[j] = c
                I_batt += u[j] * c
                copper += c * c * (R_a * elec[{C.ELEC_RA_SCALE} + j])
                conv += (k_e - eta * k_t) * c * phid[j]
                tau[j] = eta * k_t * c
            dX[{X_E_BATT}] = V * I_batt
            dX[{X_E_COPPER}] = copper
            dX[{X_E_CONV}] = conv
            dX[{X_E_QUIESCENT}] = V * I_q
            Vb[0] = V
            Ib[0] = I_batt
        """),
        "# wheel-axle torques",
        body["wheel_torque"],
        "# roller-axis forces",
        body["roller_force"],
        "# body forces",
        body["body_force"],
        "# term states",
        *s_store,
        "# mechanics",
        "if ground:",
        _indent(L(f"""
            mass = rv[{rv["mass"]}]
            g0 = fb[0] + mass * Xt[5] * Xt[4]
            g1 = fb[1] - mass * Xt[5] * Xt[3]
            g2 = fb[2]
            for j in range(4):
                g0 += Rm[3 * j] * tau[j] + Sm[3 * j] * fr[j]
                g1 += Rm[3 * j + 1] * tau[j] + Sm[3 * j + 1] * fr[j]
                g2 += Rm[3 * j + 2] * tau[j] + Sm[3 * j + 2] * fr[j]
            for i in range(3):
                dX[3 + i] = Minv[3 * i] * g0 + Minv[3 * i + 1] * g1 + Minv[3 * i + 2] * g2
            for j in range(4):
                dX[6 + j] = phid[j]
                dX[10 + j] = 0.0
        """), 4),
        "    # cos/sin of the heading: libm only once the heading is 0.05 rad away from the last exact",
        "    # value psr; otherwise that value rotated by the increment, whose cos/sin come from Taylor",
        "    # series (truncation < 1e-17 for |dpsi| < 0.05 rad; no error accumulates)",
        _indent(L("""
            if abs(Xt[2] - psr[0]) >= 0.05:
                psr[0] = Xt[2]
                cref[0] = math.cos(psr[0])
                sref[0] = math.sin(psr[0])
        """), 4),
        _indent(L("""
            dpsi = Xt[2] - psr[0]
            d2 = dpsi * dpsi
            cd = 1.0 - d2 * (0.5 - d2 * (1.0 / 24.0 - d2 * (1.0 / 720.0 - d2 * (1.0 / 40320.0))))
            sd = dpsi * (1.0 - d2 * (1.0 / 6.0 - d2 * (1.0 / 120.0 - d2 * (1.0 / 5040.0))))
            cpsi = cref[0] * cd - sref[0] * sd
            spsi = sref[0] * cd + cref[0] * sd
            dX[0] = cpsi * Xt[3] - spsi * Xt[4]
            dX[1] = spsi * Xt[3] + cpsi * Xt[4]
            dX[2] = Xt[5]
        """), 4),
        "else:",
        _indent(L(f"""
            I_w = rv[{rv["I_w"]}]
            for j in range(6):
                dX[j] = 0.0
            for j in range(4):
                dX[6 + j] = phid[j]
                dX[10 + j] = tau[j] / I_w
        """), 4),
        "# auxiliary signals (recorded from the first stage only)",
        "if stage == 0:",
        _indent(L("""
            for j in range(4):
                aux[j] = cur[j]
                aux[6 + j] = u[j]
                aux[10 + j] = FN[j]
            aux[4] = Vb[0]
            aux[5] = Ib[0]
        """), 4),
        "# ---- end of derivative ----",
    ])

    views = [f"SB = np.zeros({sum(n for _, n in slots) * W})"]
    off, xt = 0, 0
    for name, n in slots:
        views.append(f"{name} = SB[{off}:{off + n * W}]")
        if name == "Xt":
            xt = off
        off += n * W
    # the hooks read pose, body velocity and wheel angles straight from the stage state Xt
    views += [f"q = SB[{xt}:{xt + 3 * W}]", f"v = SB[{xt + 3 * W}:{xt + 6 * W}]",
              f"phi = SB[{xt + 6 * W}:{xt + 10 * W}]"]
    setup = L("\n".join([
        "b = bs[k]",
        f"for i in range({nx}):\n    X[i] = X0[b, i]",
        f"for i in range({len(RV_NAMES)}):\n    rv[i] = RV[b, i]",
        "for i in range(4):\n    for m in range(3):\n        Rm[3 * i + m] = Rm_[b, i, m]\n        Sm[3 * i + m] = Sm_[b, i, m]",
        "for i in range(3):\n    for m in range(3):\n        Minv[3 * i + m] = Minv_[b, i, m]\n        Mb[3 * i + m] = M[b, i, m]",
        *p_fill,
        f'ctx[{C.CTX_MODE}] = rv[{rv["mode"]}]', f'ctx[{C.CTX_W}] = rv[{rv["W"]}]',
        f'ctx[{C.CTX_MASS}] = rv[{rv["mass"]}]', f'ctx[{C.CTX_L}] = rv[{rv["L"]}]',
        f'ctx[{C.CTX_LW}] = rv[{rv["l"]}]', f'ctx[{C.CTX_R}] = rv[{rv["r"]}]',
        f"ctx[{C.CTX_G}] = {C.GRAVITY}",
        f'ctx[{C.CTX_SIGN_PHI}] = rv[{rv["sign_width_phi"]}]',
        f'ctx[{C.CTX_SIGN_SIGMA}] = rv[{rv["sign_width_sigma"]}]',
        f'ctx[{C.CTX_V_NOMINAL}] = rv[{rv["V_batt"]}]',
        "psr[0] = X[2]", "cref[0] = math.cos(psr[0])", "sref[0] = math.sin(psr[0])",
    ]), uses_lane=True)
    paper = ", ".join("1" if t.core else "0" for t in lay.terms)
    # the lean copy integrates only the state entries up to the last one the paper's terms
    # change (an effect's energy and states keep their initial values while it is off)
    paper_entries = 1 + max([NX_FIXED - 1] + [NX_FIXED + k for k, t in enumerate(lay.terms) if t.core]
                            + [NX_FIXED + nt + lay.state_offset[k] + t.n_states - 1
                               for k, t in enumerate(lay.terms) if t.core and t.n_states])
    # adaptive sub-steps on the ground (ADAPT_LIMITS): the rate bound of one lane from its
    # wheel speeds ad_w and roller slips ad_s, each brought closer to zero by its change ad_dw, ad_ds
    def rate(change: str) -> str:
        return (
            "ad_fp = 0.0\n"
            "ad_fs = 0.0\n"
            "for j in range(4):\n"
            "    ad_w = Rm[3 * j] * X[3] + Rm[3 * j + 1] * X[4] + Rm[3 * j + 2] * X[5]\n"
            "    ad_s = Sm[3 * j] * X[3] + Sm[3 * j + 1] * X[4] + Sm[3 * j + 2] * X[5]\n"
            + textwrap.indent(textwrap.dedent(change).strip("\n"), "    ") + "\n"
            f"    ad_xw = max(abs(ad_w) - {ADAPT_MARGIN!r} * abs(ad_dw), 0.0) / rv[{rv['sign_width_phi']}]\n"
            f"    ad_xs = max(abs(ad_s) - {ADAPT_MARGIN!r} * abs(ad_ds), 0.0) / rv[{rv['sign_width_sigma']}]\n"
            "    ad_th = math.tanh(ad_xw)\n"
            "    ad_fp = max(ad_fp, 1.0 - ad_th * ad_th)\n"
            "    ad_q = 1.0 + ad_xs * ad_xs\n"
            "    ad_fs = max(ad_fs, 1.0 / (ad_q * math.sqrt(ad_q)))\n"
            f"ad_lam = rv[{rv['lam_base']}] + rv[{rv['lam_phi']}] * ad_fp + rv[{rv['lam_sigma']}] * ad_fs\n"
            "ad_n = float(min(max(math.ceil(ad_lam * dt / ad_limit), 1), substeps))\n")
    adapt_choose = L(
        f"if rv[{rv['lam_phi']}] + rv[{rv['lam_sigma']}] > 0.0:\n" + textwrap.indent(rate("""
            ad_dw = ad_w - pspd[j]
            ad_ds = ad_s - pspd[4 + j]
            pspd[j] = ad_w
            pspd[4 + j] = ad_s
        """) + "if n > 0 and ad_n < nk[0]:\n    nk[0] = ad_n\n    hl[0] = dt / ad_n\n", "    "))
    adapt_check = L(
        "if nk[0] < substeps:\n" + textwrap.indent(rate("""
            ad_w0 = Rm[3 * j] * Xs[3] + Rm[3 * j + 1] * Xs[4] + Rm[3 * j + 2] * Xs[5]
            ad_s0 = Sm[3 * j] * Xs[3] + Sm[3 * j + 1] * Xs[4] + Sm[3 * j + 2] * Xs[5]
            ad_dw = ad_w - ad_w0
            ad_ds = ad_s - ad_s0
            if ad_w * ad_w0 <= 0.0:
                ad_dw = 1e300
            if ad_s * ad_s0 <= 0.0:
                ad_ds = 1e300
        """) + "if ad_n > nk[0]:\n    nk[0] = substeps\n    hl[0] = h\n    ad_redo = True\n", "    "))
    groups = "\n\n\n".join(
        _GROUP_TEMPLATE.format(name=name, what=what, views=_indent("\n".join(views), 4), setup=_indent(setup, 4),
                               adapt_choose=_indent(adapt_choose, 12), adapt_check=_indent(adapt_check, 14),
                               ad_limit_heun=ADAPT_LIMITS[METHOD_HEUN], ad_limit_rk4=ADAPT_LIMITS[METHOD_RK4],
                               deriv=_indent(derivative(paper_only), 16), ground=C.MODE_GROUND, rk4=METHOD_RK4,
                               n_int=paper_entries if paper_only else nx, probe=repr(STICK_PROBE),
                               e_stick=NX_FIXED + lay.index("transmission_friction"), i_w=rv["I_w"],
                               lam_phi=rv["lam_phi"], lam_sigma=rv["lam_sigma"])
        for name, what, paper_only in (
            ("_group", "every term", False),
            ("_group_paper", "the paper's terms only (every effect is off in the group)", True)))
    return _TEMPLATE.format(
        imports="\n".join(sorted(hook_imports)), nx=nx, nt=nt, W=W, mode=rv["mode"], ground=C.MODE_GROUND,
        naux=NAUX, naux_last=NAUX - 1, i_w=rv["I_w"], hooks=("\n" * 3).join(hook_defs), groups=groups,
        paper=paper)


_TEMPLATE = '''\
# Generated by omnibench.model.kernel from the registered terms. Do not edit.
import math
import numpy as np
from numba import njit, prange
from omnibench.model.fpu import flush_subnormals, restore_fpu
{imports}

NX = {nx}
NT = {nt}
W = {W}
MODE = {mode}
PAPER = np.array([{paper}], dtype=np.bool_)  # which terms are the paper's own (always on)

# every hook in lane form (omnibench.model.lanes), inlined at numba IR level into the derivative
{hooks}


{groups}


@njit(cache=True)
def _groups(RV, EN, SUB):
    """Trajectories in lane groups of W that share sub-steps, mode and enabled terms (these
    decide the kernel's branches); a short group is padded with its first trajectory.
    Returns (groups (G, W), number of real trajectories in each, whether only the paper's
    terms are on in it)."""
    B = RV.shape[0]
    run_key = np.empty(B, dtype=np.int64)  # sub-steps and mode
    terms_key = np.empty(B, dtype=np.int64)  # one bit per enabled term (NT <= 62)
    for b in range(B):
        run_key[b] = (SUB[b] if SUB.shape[0] > 1 else SUB[0]) * 2 + (0 if RV[b, MODE] == {ground} else 1)
        kk = 0
        for i in range(NT):
            kk = kk * 2 + (1 if EN[b, i] != 0.0 else 0)
        terms_key[b] = kk
    order = np.argsort(terms_key, kind="mergesort")
    order = order[np.argsort(run_key[order], kind="mergesort")]  # stable: by run, then terms
    groups = np.empty((B, W), dtype=np.int64)
    counts = np.empty(B, dtype=np.int64)
    paper = np.empty(B, dtype=np.bool_)
    G = 0
    i = 0
    while i < B:
        n = 1
        while (n < W and i + n < B and run_key[order[i + n]] == run_key[order[i]]
               and terms_key[order[i + n]] == terms_key[order[i]]):
            n += 1
        for m in range(W):
            groups[G, m] = order[i + m] if m < n else order[i]
        counts[G] = n
        paper[G] = True
        for t in range(NT):
            if EN[order[i], t] != 0.0 and not PAPER[t]:
                paper[G] = False
        i += n
        G += 1
    return groups[:G], counts[:G], paper[:G]


@njit(cache=True)
def _run_group(bs, n_valid, paper, X0, RV, P, EN, Rm, Sm, Minv, M, cmd_idx, U, t0, dt, SUB, method, rec_every,
               REC, XF):
    """One lane group, with the lean copy of the loop when only the paper's terms are on;
    subnormal doubles flushed to zero meanwhile on this thread (omnibench.model.fpu)."""
    fpu_state = flush_subnormals()
    if paper:
        _group_paper(bs, n_valid, X0, RV, P, EN, Rm, Sm, Minv, M, cmd_idx, U, t0, dt, SUB, method, rec_every, REC, XF)
    else:
        _group(bs, n_valid, X0, RV, P, EN, Rm, Sm, Minv, M, cmd_idx, U, t0, dt, SUB, method, rec_every, REC, XF)
    restore_fpu(fpu_state)


@njit(cache=True, parallel=True)
def run(X0, RV, P, EN, Rm, Sm, Minv, M, cmd_idx, U, t0, dt, SUB, method, rec_every, REC):
    """Integrate B trajectories for len(cmd_idx) steps of dt; record every rec_every steps.

    SUB: sub-steps per physics step, one per trajectory (or a single value for all)."""
    XF = np.empty_like(X0)
    groups, counts, paper = _groups(RV, EN, SUB)
    for g in prange(groups.shape[0]):
        _run_group(groups[g], counts[g], paper[g], X0, RV, P, EN, Rm, Sm, Minv, M, cmd_idx, U, t0, dt, SUB,
                   method, rec_every, REC, XF)
    return XF


@njit(cache=True)
def run_serial(X0, RV, P, EN, Rm, Sm, Minv, M, cmd_idx, U, t0, dt, SUB, method, rec_every, REC):
    """`run` on the calling thread only: for one or a few groups (the stepping simulator),
    where waking the worker threads would cost more than the work."""
    XF = np.empty_like(X0)
    groups, counts, paper = _groups(RV, EN, SUB)
    for g in range(groups.shape[0]):
        _run_group(groups[g], counts[g], paper[g], X0, RV, P, EN, Rm, Sm, Minv, M, cmd_idx, U, t0, dt, SUB,
                   method, rec_every, REC, XF)
    return XF


@njit(cache=True)
def _record(REC, b, r, X, aux, Mb, rv, k):
    """Row r of trajectory b: lane k's state, auxiliary signals and kinetic energy."""
    if REC.shape[1] == 0:
        return
    for i in range(NX):
        REC[b, r, i] = X[i * W + k]
    ke = 0.0
    if rv[MODE * W + k] == {ground}:
        for i in range(3):
            for m in range(3):
                ke += 0.5 * X[(3 + i) * W + k] * Mb[(3 * i + m) * W + k] * X[(3 + m) * W + k]
    else:
        for j in range(4):
            ke += 0.5 * rv[{i_w} * W + k] * X[(10 + j) * W + k] * X[(10 + j) * W + k]
    aux[{naux_last} * W + k] = ke
    for i in range({naux}):
        REC[b, r, NX + i] = aux[i * W + k]
'''


_GROUP_TEMPLATE = '''\
@njit(cache=True, error_model="numpy", fastmath={{"contract"}})
def {name}(bs, n_valid, X0, RV, P, EN_, Rm_, Sm_, Minv_, M, cmd_idx, U, t0, dt, SUB, method, rec_every, REC, XF):
    """Integrate the W trajectories bs (the first n_valid are real, the rest pad) in lockstep;
    the derivative with {what}."""
    n_steps = cmd_idx.shape[0]
    # one scratch buffer, every lane array a flat view at a constant offset: LLVM can prove
    # they never overlap, keeps the index arithmetic constant and vectorises over the lanes
{views}
    EN = np.empty(NT)
    for i in range(NT):
        EN[i] = EN_[bs[0], i]  # the same in every lane of a group
    ground = RV[bs[0], MODE] == {ground}
    ub = np.empty(W, dtype=np.int64)
    for k in range(W):
        ub[k] = bs[k] if U.shape[0] > 1 else 0
{setup}
    for i in range(NX * W):
        Xt[i] = X[i]  # entries this copy does not integrate keep Xt = X throughout
    substeps = SUB[bs[0]] if SUB.shape[0] > 1 else SUB[0]
    rk4 = method == {rk4}
    n_stages = 4 if rk4 else 2
    h = dt / substeps
    ad_limit = {ad_limit_rk4} if rk4 else {ad_limit_heun}
    # adaptive sub-steps (ADAPT_LIMITS) on the ground when a lane's rates are split
    adapt = False
    if ground:
        for k in range(W):
            if rv[{lam_phi} * W + k] + rv[{lam_sigma} * W + k] > 0.0:
                adapt = True
    r = 0
    # the extra pass n == n_steps only evaluates the final state, for the last record
    for n in range(n_steps + 1):
        if n == n_steps:
            if not (n_steps % rec_every == 0 and r < REC.shape[1]):
                break
            ci = cmd_idx[n_steps - 1]
            n_sub = 1
        else:
            ci = cmd_idx[n]
            n_sub = substeps
        for j in range(4):
            for k in range(W):
                ucmd[j * W + k] = U[ub[k], ci, j]
        # each lane's sub-steps nk and sub-step hl; a lane with fewer than the group's n_sub is
        # held still (hs = 0) for the rest of them
        for k in range(W):
            nk[k] = n_sub
            hl[k] = h
        if adapt and n < n_steps:
{adapt_choose}
            n_sub = 0
            for k in range(W):
                n_sub = max(n_sub, int(nk[k]))
            for i in range({n_int} * W):
                Xs[i] = X[i]
        r_start = r
        ad_redo = True
        while ad_redo:
          ad_redo = False
          for sub in range(n_sub):
            t = t0 + n * dt + sub * h
            for k in range(W):
                tb[k] = t0 + n * dt + sub * hl[k]
                hs[k] = hl[k] if sub < nk[k] else 0.0
            # Stick-slip upside down (see EXACT_SIGN_WIDTH). Passes s = 0, 1 probe the wheels at
            # rest at the start of the step: those that stay stuck are held at zero speed through
            # the step (no motion, no power); passes 2 .. n_stages + 1 are the integrator's
            # stages; the last two probe the wheels whose speed reached or crossed zero inside
            # the step, and stop those that stick.
            probing = False
            holding = False
            if not ground:
                for i in range(4 * W):
                    w0[i] = X[10 * W + i]
                    a0[i] = X[6 * W + i]
                    hold[i] = 0.0
                    chk[i] = 1.0 if w0[i] == 0.0 else 0.0
                    if chk[i] != 0.0:
                        probing = True
            for s in range(n_stages + 4):
                stage = s - 2
                if stage < 0 or stage >= n_stages:
                    if not probing:
                        if stage < 0:
                            continue
                        break
                    for k in range(W):
                        tl[k] = tb[k] if stage < 0 else tb[k] + hl[k]
                    side = {probe} if s % 2 == 0 else -{probe}
                    for i in range({n_int} * W):
                        Xt[i] = X[i]
                    for i in range(4 * W):
                        if chk[i] != 0.0:
                            Xt[10 * W + i] = side
                    stage = -1  # no auxiliary signals from a probe
                elif stage == 0:
                    for k in range(W):
                        tl[k] = tb[k]
                    for i in range({n_int} * W):
                        Xt[i] = X[i]
                else:
                    for k in range(W):
                        tl[k] = tb[k] + 0.5 * hl[k] if rk4 and stage < 3 else tb[k] + hl[k]
                    if not ground:
                        # a stage that reached or crossed zero speed: the sign's jump is inside
                        # the step (an explicit step would bounce off it), so probe at its end
                        for i in range(4 * W):
                            if w0[i] * Xt[10 * W + i] <= 0.0 and hold[i] == 0.0:
                                chk[i] = 1.0
{deriv}
                if stage < 0:
                    if s % 2 == 0:
                        for i in range(4 * W):
                            acc_p[i] = dX[10 * W + i]
                    elif s == 1:
                        # stuck wheels at the start: held at rest through the step
                        for i in range(4 * W):
                            if chk[i] != 0.0 and acc_p[i] <= 0.0 and dX[10 * W + i] >= 0.0:
                                hold[i] = 1.0
                                holding = True
                            chk[i] = 0.0
                        probing = False
                    else:
                        for j in range(4):
                            for k in range(W):
                                i = j * W + k
                                if chk[i] != 0.0 and acc_p[i] <= 0.0 and dX[10 * W + i] >= 0.0:
                                    w = X[10 * W + i]
                                    X[{e_stick} * W + k] += 0.5 * rv[{i_w} * W + k] * w * w
                                    X[10 * W + i] = 0.0
                                    X[6 * W + i] = a0[i]  # a stuck wheel has not turned
                    continue
                if holding:
                    for i in range(4 * W):
                        if hold[i] != 0.0:
                            dX[10 * W + i] = 0.0
                if stage == 0:
                    if sub == 0 and n % rec_every == 0:
                        for k in range(n_valid):
                            _record(REC, bs[k], r, X, aux, Mb, rv, k)
                        r += 1
                    if n == n_steps:
                        break
                    if rk4 and adapt:
                        for e in range({n_int}):
                            for k in range(W):
                                i = e * W + k
                                acc[i] = dX[i]
                                Xt[i] = X[i] + 0.5 * hs[k] * dX[i]
                    elif rk4:
                        for i in range({n_int} * W):
                            acc[i] = dX[i]
                            Xt[i] = X[i] + 0.5 * h * dX[i]
                    elif adapt:
                        for e in range({n_int}):
                            for k in range(W):
                                i = e * W + k
                                acc[i] = dX[i]
                                Xt[i] = X[i] + hs[k] * dX[i]
                    else:
                        for i in range({n_int} * W):
                            acc[i] = dX[i]
                            Xt[i] = X[i] + h * dX[i]
                elif rk4:
                    if stage == 1:
                        if adapt:
                            for e in range({n_int}):
                                for k in range(W):
                                    i = e * W + k
                                    acc[i] = acc[i] + 2.0 * dX[i]
                                    Xt[i] = X[i] + 0.5 * hs[k] * dX[i]
                        else:
                            for i in range({n_int} * W):
                                acc[i] = acc[i] + 2.0 * dX[i]
                                Xt[i] = X[i] + 0.5 * h * dX[i]
                    elif stage == 2:
                        if adapt:
                            for e in range({n_int}):
                                for k in range(W):
                                    i = e * W + k
                                    acc[i] = acc[i] + 2.0 * dX[i]
                                    Xt[i] = X[i] + hs[k] * dX[i]
                        else:
                            for i in range({n_int} * W):
                                acc[i] = acc[i] + 2.0 * dX[i]
                                Xt[i] = X[i] + h * dX[i]
                    elif adapt:
                        for e in range({n_int}):
                            for k in range(W):
                                i = e * W + k
                                X[i] += hs[k] / 6.0 * (acc[i] + dX[i])
                    else:
                        for i in range({n_int} * W):
                            X[i] += h / 6.0 * (acc[i] + dX[i])
                elif adapt:
                    for e in range({n_int}):
                        for k in range(W):
                            i = e * W + k
                            X[i] += 0.5 * hs[k] * (acc[i] + dX[i])
                else:
                    for i in range({n_int} * W):
                        X[i] += 0.5 * h * (acc[i] + dX[i])
                if stage == n_stages - 1 and not ground:
                    for i in range(4 * W):
                        if w0[i] * X[10 * W + i] <= 0.0 and hold[i] == 0.0:
                            chk[i] = 1.0
                        if chk[i] != 0.0:
                            probing = True
          if adapt and n < n_steps:
              # the bound again on the speeds at the end of the step: a lane that fails is
              # stepped again from the saved state with the fixed count
{adapt_check}
              if ad_redo:
                  for i in range({n_int} * W):
                      X[i] = Xs[i]
                  r = r_start
                  n_sub = substeps
    for k in range(n_valid):
        for i in range(NX):
            XF[bs[k], i] = X[i * W + k]
'''


_CACHE: dict[str, object] = {}


def _cache_dir() -> Path:
    path = cache_root() / "kernels"
    try:
        path.mkdir(parents=True, exist_ok=True)
        probe = path / f".write-test-{os.getpid()}"  # per process: parallel test workers share the folder
        probe.write_text("ok")
        probe.unlink()
        return path
    except OSError:
        path = Path(tempfile.gettempdir()) / "omnibench-kernels"
        path.mkdir(parents=True, exist_ok=True)
        return path


def load_kernel(lay: Layout | None = None):
    """The compiled kernel module for the current registry (generated and cached on disk)."""
    lay = lay or layout()
    last = _LAST.get("kernel")
    if last is not None and last[0] is lay:
        return last[1]  # same registry as last call: skip regenerating and hashing the source
    module = _load(lay)
    _LAST["kernel"] = (lay, module)
    return module


_LAST: dict[str, tuple[Layout, object]] = {}


def _inputs_key(lay: Layout) -> str:
    """A digest of everything `_source` reads, without generating it (~0.15 s of CPU, a fifth of
    loading the cached kernel): the Python and numpy versions, WIDTH, the layout (each term's
    name, kind, sizes, hooks and where they live), the files of the hooks' modules and of every
    omnibench module loaded now (the generator, the lanes rewriter, the terms, their helpers and
    constants). It only names the generated file (`_load`'s own key): a change it over-counts
    costs one generation, not a compile."""
    h = hashlib.sha256(f"{sys.version}\0{np_version()}\0{WIDTH}\0".encode())
    h.update(repr((lay.param_offset, lay.state_offset, lay.n_params, lay.n_states)).encode())
    files: set[str] = set()
    for term in lay.terms:
        h.update(repr((term.name, term.core, len(term.params), term.n_states)).encode())
        for hook, fn in term.hooks.items():
            f = getattr(fn, "py_func", fn)
            h.update(f"{hook}\0{f.__module__}\0{f.__qualname__}\0".encode())
            files.add(str(getattr(sys.modules.get(f.__module__), "__file__", None) or f.__module__))
    for name, mod in list(sys.modules.items()):
        if name == "omnibench" or name.startswith("omnibench."):
            files.add(str(getattr(mod, "__file__", None) or name))
    for f in sorted(files):
        h.update(f.encode())
        try:
            h.update(Path(f).read_bytes())
        except OSError:
            h.update(b"\0missing")
    return h.hexdigest()[:32]


def np_version() -> str:
    """numpy's version (part of `_inputs_key`: hooks may use its constants)."""
    import numpy

    return str(numpy.__version__)


def _source_key(lay: Layout) -> tuple[str, str | None]:
    """(the generated file's key, its source when it had to be generated). The key of a layout
    whose inputs (`_inputs_key`) were seen before is read from a small file beside the kernels;
    otherwise the source is generated and hashed (`_digest`) and the key remembered."""
    folder = _cache_dir()
    ikey = _inputs_key(lay)
    note = folder / f"omnibench_kernel_inputs_{ikey}.key"
    try:
        key = note.read_text().strip()
    except OSError:
        key = ""
    if len(key) == 16 and all(c in "0123456789abcdef" for c in key) and (folder / f"omnibench_kernel_{key}.py").exists():
        return key, None
    src = _source(lay)
    key = _digest(src, lay)
    try:
        tmp = note.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_text(key)
        os.replace(tmp, note)
    except OSError:
        pass
    return key, src


def _digest(src: str, lay: Layout) -> str:
    """The generated file's key: a digest of its source, this module and the hooks' code."""
    digest = hashlib.sha256(src.encode())
    digest.update(inspect.getsource(sys.modules[__name__]).encode())
    # numba's cache of the generated module does not see changes in the code it imports, so
    # the key covers the whole source of every module a hook comes from (helpers included)
    modules = {"omnibench.model.smooth", "omnibench.model.context", "omnibench.model.fpu"}
    for term in lay.terms:
        for fn in term.hooks.values():
            modules.add(getattr(fn, "py_func", fn).__module__)
            digest.update(inspect.getsource(getattr(fn, "py_func", fn)).encode())
    for mod in sorted(modules):
        try:
            digest.update(inspect.getsource(sys.modules[mod]).encode())
        except (KeyError, OSError, TypeError):
            digest.update(mod.encode())
    return digest.hexdigest()[:16]


def _load(lay: Layout):
    key, src = _source_key(lay)
    if key in _CACHE:
        return _CACHE[key]
    path = _cache_dir() / f"omnibench_kernel_{key}.py"
    if not path.exists():
        tmp = path.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_text(src if src is not None else _source(lay))
        os.replace(tmp, path)
    module = _exec_generated(path)
    _compile(module)
    _CACHE[key] = module
    return module


def _exec_generated(path: Path):
    """The generated kernel file at `path`, imported as a module (its functions not compiled yet)."""
    name = path.stem
    spec = importlib.util.spec_from_file_location(name, path)
    if spec is None or spec.loader is None:
        raise ImportError(f"cannot load the generated kernel {path}")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


def _run_signature():
    from numba import types

    f2, f3 = types.float64[:, ::1], types.float64[:, :, ::1]
    i1 = types.int64[::1]
    return (f2, f2, f2, f2, f3, f3, f3, f3, i1, f3, types.float64, types.float64, i1, types.int64,
            types.int64, f3)


def _compile(module) -> None:
    """Load `run` and `run_serial` from numba's disk cache, compiling them first in a child
    process when the cache has not got them (the first run on a machine or code version).

    A process that compiled the kernel itself computes with code that is not bit for bit what it
    wrote to the cache: on a clean campaign's runs 29 of 428 predictions differed by up to 2.6e-15
    relative from every later process's, so the first `omnibench fit` on a machine wrote other last
    digits (~1e-5 SE) than a re-run. Every process now runs the cached code. When the child cannot
    compile it (a term registered only in this process: the child imports the generated file, and
    through it the hooks' modules, but runs none of this process's registrations), it is compiled
    here, as before. Processes that find the cache cold at once (test workers, a campaign and its
    simulated board) take turns on a lock in the cache folder: one compiles, the others then load.
    tests/model/test_kernel_cache.py checks a cold cache against a warm one."""
    if not _cached_on_disk(module):
        path = Path(module.__file__)
        _tell_a_person(COMPILING)
        with waiting_lock(path.parent / ".compile.lock"):
            # compiled by another process while this one waited? if not, by a child; if the
            # child cannot, here, still holding the lock (the waiting processes then load it)
            if not _cached_on_disk(module) and not _compile_in_child(path):
                _compile_here(module)
                return
    _compile_here(module)


#: Said on a terminal before the compile (or the wait for another process's): the first simulation
#: on a machine is otherwise a silent half minute to two minutes.
COMPILING = ("omnibench: compiling the physics kernel for this machine and code version "
             "(once; about 30 s, up to 2 min on a slow machine)")


def _tell_a_person(line: str) -> None:
    """Print `line` on stderr when a person reads it there (a terminal), never into a pipe or file."""
    stream = sys.stderr
    try:
        if stream is not None and stream.isatty():
            print(line, file=stream, flush=True)
    except (OSError, ValueError):
        pass


def _cached_on_disk(module) -> bool:
    """Whether numba's cache holds both entry points of this generated file for this machine:
    its index (beside the file, or under NUMBA_CACHE_DIR) has an entry for the simulator's
    signature, this CPU and this source (numba drops an index of another source or numba
    version). Read through numba's own cache objects; with another numba's internals, whether
    an index file is there at all."""
    sig = _run_signature()
    for fn in (module.run, module.run_serial):
        try:
            cache = fn._cache
            if cache._index_key(sig, fn.targetctx.codegen()) not in cache._cache_file._load_index():
                return False
        except AttributeError:
            path = Path(module.__file__)
            if not any((path.parent / "__pycache__").glob(f"{path.stem}.{fn.__name__}-*.nbi")):
                return False
    return True


#: s a child may take to compile the kernel (~30 s, 2 min on a slow machine) before it is given up
CHILD_COMPILE_TIMEOUT_S = 1800.0


def _compile_in_child(path: Path) -> bool:
    """Compile the generated kernel at `path` into numba's cache in a child Python; True if it did."""
    import subprocess

    code = "import sys; from omnibench.model import kernel; kernel._compile_file(sys.argv[1])"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(os.path.abspath(p or os.curdir) for p in sys.path))
    flags = subprocess._args_from_interpreter_flags()  # type: ignore[attr-defined]  # -s, -I, -X ... as this one
    try:
        done = subprocess.run([sys.executable, *flags, "-c", code, str(path)], env=env, capture_output=True,
                              check=False, timeout=CHILD_COMPILE_TIMEOUT_S)
    except (OSError, subprocess.TimeoutExpired) as exc:
        logging.getLogger(__name__).debug("kernel compile in a child failed: %s", exc)
        return False
    if done.returncode != 0:
        tail = done.stderr.decode(errors="replace").strip().splitlines()[-1:]
        logging.getLogger(__name__).debug("kernel compile in a child failed (exit %d): %s", done.returncode,
                                          tail[0] if tail else "")
    return done.returncode == 0


def _compile_file(path: str) -> None:
    """The child's side of `_compile_in_child`: import the generated file and compile it."""
    _compile_here(_exec_generated(Path(path)))


def _compile_here(module) -> None:
    """Compile `run` for the simulator's argument types in this process (or load it from numba's
    cache), with LLVM's SLP vectoriser on (numba leaves it off by default): with the loop vectoriser it
    turns the unrolled loops over the lanes into vector instructions. The tests in
    tests/model/test_kernel_numerics.py check the compiled kernel against a plain numpy model."""
    from numba.core import config

    previous = config.SLP_VECTORIZE  # type: ignore[attr-defined]  # set at runtime by numba's config reload
    config.SLP_VECTORIZE = 1  # type: ignore[attr-defined]  # (same)
    try:
        module.run.compile(_run_signature())
        module.run_serial.compile(_run_signature())
    finally:
        config.SLP_VECTORIZE = previous  # type: ignore[attr-defined]  # (same)
