"""Every test gets its own rig state folder (``neck_env.rig.memory``): no test reads the thermal
history another test, or the user's own rig, left behind."""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path

import pytest

# Under pytest-xdist each worker has a core of its own: numba's threads would only contend with
# the other worker's (set before anything imports numba; the plant's prange loops run rig by rig,
# so their results do not depend on the thread count).
if os.environ.get("PYTEST_XDIST_WORKER"):
    os.environ.setdefault("NUMBA_NUM_THREADS", "1")


@pytest.fixture(autouse=True)
def _rig_state_dir(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("NECK_RIG_STATE_DIR", str(tmp_path_factory.mktemp("rig_state")))



def _benchmark(name: str):
    """``benchmarks/<name>.py`` as a module (the benchmarks are scripts, not a package)."""
    path = Path(__file__).resolve().parents[1] / "benchmarks" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture
def gap_blind_script():
    return _benchmark("gap_blind")


@pytest.fixture
def gap_shapes_script():
    return _benchmark("gap_shapes")
