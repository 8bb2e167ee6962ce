"""pint's definition cache is kept per pint installation: a cache written by another environment
(since deleted) must not make every command pay the uncached parse."""

from __future__ import annotations

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
        assert units.to_si("45 deg", "rad") == pytest.approx(0.7853981633974483)
        written = list(Path(units.pint_cache_folder()).glob("*"))
        assert written, "pint wrote no cache entry in omnibench's folder"
    finally:
        units.registry.cache_clear()
