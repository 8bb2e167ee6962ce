"""The lane form of the hooks (omnibench.model.lanes): each registered hook, rewritten for lane
k of a structure-of-arrays group, must do exactly what the hook does to that trajectory alone;
hooks the rewrite cannot handle are refused with a message naming them."""

from __future__ import annotations

import numpy as np
import pytest

from omnibench.model import context as C
from omnibench.model.lanes import HookFormError, lane_block, lane_function
from omnibench.model.terms import layout

W = 4
# argument sizes of each hook kind (omnibench.model.terms), "ns" = the term's own states
SIZES = {
    "normal_force": (4, C.CTX_SIZE, "np"),
    "duty": (4, C.CTX_SIZE, "np"),
    "electrical": (C.ELEC_SIZE, "ns", C.CTX_SIZE, "np"),
    "wheel_torque": (4, 4, 4, 4, 4, "ns", C.CTX_SIZE, "np"),
    "roller_force": (4, 4, 4, C.CTX_SIZE, "np"),
    "body_force": (3, 3, 3, C.CTX_SIZE, "np"),
    "state_derivative": ("ns", "ns", 4, 4, C.ELEC_SIZE, C.CTX_SIZE, "np"),
}


def _lane_callable(fn, width: int):
    src, needed = lane_function(fn, "lane_hook", width, prefix="g_")
    namespace = {alias: obj for alias, (obj, _) in needed.items()}
    exec(src, namespace)  # plain Python: the same operations the kernel compiles
    return namespace["lane_hook"]


def _hooks():
    for term in layout().terms:
        for hook, fn in term.hooks.items():
            yield pytest.param(term, hook, fn, id=f"{term.name}.{hook}")


def _random_arguments(term, hook, rng):
    """One trajectory's arguments per lane, as lists of arrays (lane-major)."""
    sizes = [len(term.params) if s == "np" else term.n_states if s == "ns" else s for s in SIZES[hook]]
    lanes = []
    for k in range(W):
        args = [rng.uniform(-2.0, 2.0, n) for n in sizes]
        ctx_pos = [i for i, s in enumerate(SIZES[hook]) if s == C.CTX_SIZE][-1]
        ctx = args[ctx_pos]
        ctx[C.CTX_MODE] = float(k % 2)  # ground and upside down side by side
        for slot in (C.CTX_W, C.CTX_MASS, C.CTX_L, C.CTX_LW, C.CTX_R, C.CTX_G, C.CTX_SIGN_PHI,
                     C.CTX_SIGN_SIGMA, C.CTX_V_NOMINAL):
            ctx[slot] = abs(ctx[slot]) + 0.1
        p = args[-1]
        p[:] = rng.uniform(0.1, 2.0, p.size)  # sizes, widths and time constants are positive
        if k == 3:
            p[:] = 0.0  # a lane with the term switched off: its early return must stay per lane
        lanes.append(args)
    return lanes


@pytest.mark.parametrize(("term", "hook", "fn"), list(_hooks()))
def test_lane_form_equals_the_hook_on_every_lane_and_touches_no_other(term, hook, fn):
    rng = np.random.default_rng(7)
    per_lane = _random_arguments(term, hook, rng)
    # structure of arrays: element i of lane k at i * W + k
    soa = [np.stack([per_lane[k][a] for k in range(W)], axis=1).ravel() for a in range(len(per_lane[0]))]
    lane_hook = _lane_callable(fn, W)
    py = getattr(fn, "py_func", fn)
    for k in range(W):
        mine = [a.copy() for a in soa]  # a fresh group per lane: a write to another lane shows
        lane_hook(*mine, k)
        alone = [a.copy() for a in per_lane[k]]
        py(*alone)
        for a, (got, before, want) in enumerate(zip(mine, soa, alone)):
            if not got.size:
                continue
            got, before = got.reshape(-1, W), before.reshape(-1, W)
            np.testing.assert_array_equal(got[:, k], want, err_msg=f"{term.name}.{hook}: argument {a}, lane {k}")
            np.testing.assert_array_equal(np.delete(got, k, axis=1), np.delete(before, k, axis=1),
                                          err_msg=f"{term.name}.{hook}: argument {a}: lane {k} wrote another lane")


def _slices(out, phi, phi_dot, FN, i_motor, xs, ctx, p):
    out[:] = 0.0


def _passes_array_on(out, phi, phi_dot, FN, i_motor, xs, ctx, p):
    np.copyto(out, phi)


def _returns_value(u, ctx, p):
    if p[0] == 0.0:
        return 1.0
    u[0] = 0.0


def _uses_lane_name(u, ctx, p):
    for k in range(4):
        u[k] = 0.0


def _keyword_only(u, ctx, *, p):
    u[0] = p[0]


def _nested_helper(u, ctx, p):
    def twice(x):
        return 2.0 * x
    u[0] = twice(p[0])


def _closure():
    gain = 2.0

    def hook(u, ctx, p):
        u[0] = gain * p[0]
    return hook


def _plain_decorator(f):
    return f


@_plain_decorator
def _decorated(u, ctx, p):
    u[0] = p[0]


@pytest.mark.parametrize(("fn", "message"), [
    (_slices, "one element at a time"),
    (_passes_array_on, "used whole"),
    (_returns_value, "return nothing"),
    (_uses_lane_name, "lane variable"),
    (_keyword_only, "plain positional"),
    (_nested_helper, "inside"),
    (_closure(), "enclosing function"),
    (_decorated, "@njit only"),
])
def test_hooks_the_rewrite_cannot_handle_are_refused_by_name(fn, message):
    with pytest.raises(HookFormError, match=message) as err:
        lane_function(fn, "x", W, prefix="g_")
    assert fn.__name__ in str(err.value)


W_GLOBAL = 2.0  # a hook global; the test gives the generated module a clashing name of its own


def _reads_a_module_global(u, ctx, p):
    u[0] = W_GLOBAL * p[0]


def test_hook_globals_are_renamed_so_they_cannot_clash_with_the_kernels_names():
    src, needed = lane_function(_reads_a_module_global, "x", W, prefix="m7_")
    assert needed == {"m7_W_GLOBAL": (2.0, "W_GLOBAL")}
    namespace = {"m7_W_GLOBAL": 2.0, "W_GLOBAL": -1.0}  # the module's own W_GLOBAL must not be read
    exec(src, namespace)
    u, p = np.zeros(4 * W), np.full(W, 3.0)
    namespace["x"](u, np.zeros(C.CTX_SIZE * W), p, 1)
    assert u[1] == 6.0


def test_kernel_section_is_rewritten_into_a_loop_over_the_lanes():
    code = lane_block("for j in range(2):\n    y[j] = 2.0 * x[j] + c", {"x", "y"}, 3)
    x = np.arange(6.0)  # element j of lane k at j * 3 + k
    y = np.zeros(6)
    exec(code, {"x": x, "y": y, "c": 1.0})
    np.testing.assert_array_equal(y, 2.0 * x + 1.0)
    with pytest.raises(HookFormError, match="used whole"):
        lane_block("y[0] = x.sum()", {"x", "y"}, 3)
