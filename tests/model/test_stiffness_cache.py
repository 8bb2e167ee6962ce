"""stiffness.decay_rates remembers the rate of each distinct prepared row (issue 34): the
numbers are those of a fresh computation, rows repeated in a batch or asked for again are not
computed again, and ground_split's batched probes give the splits of one probe at a time."""

from __future__ import annotations

import numpy as np

from omnibench.model import simulator, stiffness
from omnibench.model.robot import default_robot
from omnibench.model.scenario import Scenario
from omnibench.model.terms import layout


def _stack(pairs):
    lay = layout()
    preps = [simulator._prepare(r, s, lay) for r, s in pairs]
    return [np.ascontiguousarray(np.stack([getattr(p, n) for p in preps]))
            for n in ("x0", "rv", "P", "EN", "Rm", "Sm", "Minv", "M")], lay


def test_rates_equal_fresh_ones_and_each_row_is_computed_once(monkeypatch):
    robot = default_robot()
    other = robot.replace(b=0.6, b_r=1.3)
    pairs = [(robot, Scenario(mode="ground")), (other, Scenario(mode="ground", payload=3.0)),
             (robot, Scenario(mode="upside_down")), (robot, Scenario(mode="ground"))]
    arrays, lay = _stack(pairs)
    fresh = stiffness._decay_rates_of_rows(*arrays, lay)
    stiffness._RATES.clear()
    computed: list[int] = []
    real = stiffness._decay_rates_of_rows

    def counting(*args):
        computed.append(args[0].shape[0])
        return real(*args)

    monkeypatch.setattr(stiffness, "_decay_rates_of_rows", counting)
    first = stiffness.decay_rates(*arrays, lay)
    np.testing.assert_array_equal(first, fresh)
    assert computed == [3]  # the repeated first row once
    again = stiffness.decay_rates(*arrays, lay)
    np.testing.assert_array_equal(again, fresh)
    assert computed == [3]  # nothing computed again
    assert first[0] > first[2]  # the ground's regularised signs are stiffer than the exact sign upside down


def test_ground_split_equals_probe_by_probe():
    """The twelve bound probes in one kernel call give what one call per probe gives."""
    robot = default_robot()
    pairs = [(robot.replace(b=b), Scenario(mode="ground", payload=p)) for b in (0.3, 0.5) for p in (0.0, 4.0)]
    arrays, lay = _stack(pairs)
    lam = stiffness.decay_rates(*arrays, lay)
    got = stiffness._ground_split(lam, *arrays, lay)
    X0, RV, P, EN, Rm, Sm, Minv, M = arrays
    iphi, isig = stiffness.kernel.RV["sign_width_phi"], stiffness.kernel.RV["sign_width_sigma"]

    def rate(f_phi, f_sig):
        rv = RV.copy()
        rv[:, iphi] *= f_phi
        rv[:, isig] *= f_sig
        return stiffness.decay_rates(X0, rv, P, EN, Rm, Sm, Minv, M, lay)

    base = rate(stiffness.WIDE, stiffness.WIDE)
    lam_phi = np.maximum(rate(1.0, stiffness.WIDE) - base, 0.0)
    lam_sig = np.maximum(rate(stiffness.WIDE, 1.0) - base, 0.0)
    short = lam - (base + lam_phi + lam_sig)
    parts = lam_phi + lam_sig
    grow = np.where((short > 0) & (parts > 0), 1.0 + short / np.where(parts > 0, parts, 1.0), 1.0)
    base = np.where((short > 0) & (parts <= 0), lam, base)
    lam_phi, lam_sig = lam_phi * grow, lam_sig * grow
    rv = RV
    eps_phi, eps_sig, r = rv[:, iphi], rv[:, isig], rv[:, stiffness.kernel.RV["r"]]
    span = rv[:, stiffness.kernel.RV["L"]] + rv[:, stiffness.kernel.RV["l"]]
    rows = np.arange(len(pairs))
    nudge = stiffness.NUDGE * np.minimum(eps_phi * r / (1.0 + span), eps_sig / 1.5)
    for x in stiffness.SPEEDS:
        for axis in range(3):
            center = np.zeros((len(pairs), 3))
            center[:, axis] = x * eps_phi * r * (1.0 if axis < 2 else 1.0 / span)
            one = stiffness._decay_rates(rows, stiffness.GROUND_DOFS, nudge, *arrays, lay, center=center)
            w = np.einsum("bjk,bk->bj", Rm, center)
            s = np.einsum("bjk,bk->bj", Sm, center)
            f_phi = np.max(1.0 - np.tanh(np.abs(w) / eps_phi[:, None]) ** 2, axis=1)
            f_sig = np.max((1.0 + (s / eps_sig[:, None]) ** 2) ** -1.5, axis=1)
            base = base + np.maximum(one - (base + lam_phi * f_phi + lam_sig * f_sig), 0.0) * 1.2
    np.testing.assert_allclose(got, np.column_stack([base, np.maximum(lam_phi, 1e-300), lam_sig]),
                               rtol=1e-12, atol=0.0)


def test_row_keys_are_each_rows_bytes_joined() -> None:
    """The remembered rates' keys: row b's bytes of every array in order (as joining each
    array's row), for contiguous, strided, empty and one-dimensional inputs."""
    import numpy as np

    from omnibench.model.stiffness import _row_keys

    rng = np.random.default_rng(0)
    B = 5
    arrays = [rng.normal(size=(B, 3)), rng.normal(size=(B, 4, 3)), np.zeros((B, 0)), rng.normal(size=B),
              rng.normal(size=(8, B, 2))[:, :, 0].T]
    assert _row_keys(arrays, B) == [b"".join(np.ascontiguousarray(a[b]).tobytes() for a in arrays)
                                    for b in range(B)]
    arrays[3][2] += 1e-12
    keys = _row_keys(arrays, B)
    assert len(set(keys)) == B and keys[2] != keys[0]
