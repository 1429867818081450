"""Every test gets its own rig state folder (``neck_env.rig.memory``): no test reads the thermal
history another test, or the user's own rig, left behind."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest


@pytest.fixture(autouse=True)
def _rig_state_dir(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("NECK_RIG_STATE_DIR", str(tmp_path_factory.mktemp("rig_state")))



@pytest.fixture
def gap_blind_script():
    """``benchmarks/gap_blind.py`` as a module (the benchmarks are scripts, not a package)."""
    path = Path(__file__).resolve().parents[1] / "benchmarks" / "gap_blind.py"
    spec = importlib.util.spec_from_file_location("gap_blind", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod
