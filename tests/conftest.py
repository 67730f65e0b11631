"""Fixtures shared by the test modules."""

import pytest
from _demo_config import run_demo


@pytest.fixture(scope="session")
def demo_dir(tmp_path_factory):
    """One small demo run with its run config (read only: copy it to change it)."""
    return run_demo(tmp_path_factory, "demo")
