"""Fixtures of the ROS deployment tests."""

from __future__ import annotations

from pathlib import Path

import pytest

from .deploy_helpers import export_weights


@pytest.fixture(scope="session")
def weights(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """maif actor weights exported once per test run by a very short in-process training."""
    return export_weights(tmp_path_factory.mktemp("weights"), seed=2)
