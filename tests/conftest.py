"""Every test gets its own rig state folder (``neck_env.rig.memory``): no test reads the thermal
history another test, or the user's own rig, left behind."""

from __future__ import annotations

import pytest


@pytest.fixture(autouse=True)
def _rig_state_dir(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("NECK_RIG_STATE_DIR", str(tmp_path_factory.mktemp("rig_state")))
