"""Fixtures shared by the test modules, and where the tests find the shared data.

The real Lenstool models live outside the project, in ``../shared/data`` of the
development workspace. The library reads their folders from environment
variables only (:data:`lensdual.simulation.families.DATA_ENVIRONMENT`); the tests
set them here where the folders exist and the variables are not set, and the
tests that need the models skip without them.
"""

import os
from pathlib import Path

import pytest
from _demo_config import run_demo

#: The development workspace's data folder (it may be absent).
SHARED_DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
_DATA_FOLDERS = {"LENSDUAL_SMACS0723_DIR": "smacs0723_mahler2022",
                 "LENSDUAL_HFF_DIR": "hff_cats_lenstool"}

# this file is not a module of doctests (docs/conftest.py is the other "conftest")
collect_ignore = ["conftest.py"]


def pytest_configure(config):
    for env, folder in _DATA_FOLDERS.items():
        if not os.environ.get(env) and (SHARED_DATA / folder).is_dir():
            os.environ[env] = str(SHARED_DATA / folder)


@pytest.fixture(scope="session")
def demo_dir(tmp_path_factory):
    """One small demo run with its run config (read only: copy it to change it)."""
    return run_demo(tmp_path_factory, "demo")
