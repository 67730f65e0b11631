"""Point lensdual at the development workspace's real Lenstool models, if present.

The library reads the folders of the models behind the ``*_lenstool`` families
from environment variables only (``lensdual.simulation.families.DATA_ENVIRONMENT``);
the benchmarks, like the tests, set them to ``../shared/data`` where that folder
exists and the variables are not already set.
"""

import os
from pathlib import Path

SHARED_DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
FOLDERS = {"LENSDUAL_SMACS0723_DIR": "smacs0723_mahler2022",
           "LENSDUAL_HFF_DIR": "hff_cats_lenstool"}


def use_shared_data():
    """Set the data environment variables to ``../shared/data`` where it exists."""
    for env, folder in FOLDERS.items():
        if not os.environ.get(env) and (SHARED_DATA / folder).is_dir():
            os.environ[env] = str(SHARED_DATA / folder)
