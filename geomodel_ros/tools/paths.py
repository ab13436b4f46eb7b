"""Where the tools find the repository's files: config/ and the shared data beside it."""

from __future__ import annotations

import os
from pathlib import Path

#: The repository (or source tree) root: geomodel_ros/tools/paths.py -> ../../..
REPO = Path(__file__).resolve().parents[2]
CONFIG_DIR = REPO / "config"
FASTDDS_LARGE_DATA = CONFIG_DIR / "fastdds_large_data.xml"


def data_dir() -> Path:
    """Return the shared data folder: $GEOMODEL_DATA or ../shared/data beside the repository."""
    env = os.environ.get("GEOMODEL_DATA")
    return Path(env) if env else REPO.parent / "shared" / "data"
