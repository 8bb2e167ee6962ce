"""The simulator asks numba's OpenMP workers to wait passively between parallel regions (issue 34:
spinning workers took CPU from the fit's own thread on a busy machine), unless the user chose."""

from __future__ import annotations

import os
import subprocess
import sys


def _policy(value: str | None) -> str:
    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    if value is not None:
        env["OMP_WAIT_POLICY"] = value
    code = "import os, omnibench.model.simulator; print(os.environ.get('OMP_WAIT_POLICY'))"
    return subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                          check=True).stdout.strip()


def test_passive_waiting_unless_the_user_set_a_policy():
    assert _policy(None) == "passive"
    assert _policy("active") == "active"
