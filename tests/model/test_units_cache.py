"""pint's definition cache is kept per pint installation: a cache written by another environment
(since deleted) must not make every command pay the uncached parse."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import pint
import pytest

from omnibench.model import units


def test_the_cache_folder_is_omnibench_s_and_names_this_pint(monkeypatch, tmp_path) -> None:
    monkeypatch.setenv("OMNIBENCH_CACHE", str(tmp_path))
    here = units.pint_cache_folder()
    assert here.parent == tmp_path / "pint"
    monkeypatch.setattr(pint, "__file__", "/elsewhere/venv/site-packages/pint/__init__.py")
    assert units.pint_cache_folder() != here  # another environment's pint: another folder


def test_the_registry_writes_its_cache_there_and_reads_units(monkeypatch, tmp_path) -> None:
    monkeypatch.setenv("OMNIBENCH_CACHE", str(tmp_path))
    units.registry.cache_clear()
    try:
        # (degrees no longer go through pint: units.EXACT)
        assert units.to_si("1500 g", "kg") == pytest.approx(1.5)
        written = list(Path(units.pint_cache_folder()).glob("*"))
        assert written, "pint wrote no cache entry in omnibench's folder"
    finally:
        units.registry.cache_clear()


def test_degrees_without_pint_are_pint_s_own_numbers() -> None:
    """units.EXACT converts degrees without importing pint: to the last bit what pint gives."""
    import numpy as np

    rng = np.random.default_rng(34)
    values = [45.0, -45.0, 90.0, 0.0, -0.0, 1e-300, 359.999, *rng.uniform(-720, 720, 2000), *rng.normal(0, 1e-3, 200)]
    ureg = units.registry()
    for v in values:
        text = f"{float(v)!r} deg"
        want = float(ureg.Quantity(float(v), ureg.parse_units("deg")).to("rad").magnitude)
        got = units.to_si(text, "rad")
        assert got == want and math.copysign(1.0, got) == math.copysign(1.0, want), text


def test_a_robot_file_in_degrees_loads_without_pint() -> None:
    """Reading the shipped robot (roller angles in degrees) does not import pint (~0.3 s of CPU)."""
    code = ("import sys; from omnibench.model import default_robot; r = default_robot(); "
            "print('pint' in sys.modules, r.alpha)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.startswith("False"), out
