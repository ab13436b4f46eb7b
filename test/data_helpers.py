"""Access to the project's shared data (../shared/data beside the repository).

A test that needs a data file calls :func:`require`: without the file it is skipped on a
developer's machine, but fails under CI (``CI=true``), where the data must be present.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

DATA = Path(os.environ.get("GEOMODEL_DATA",
                          Path(__file__).resolve().parents[2] / "shared" / "data"))


def require(path: Path) -> Path:
    """``path`` if it exists; else skip the test, or fail it under ``CI=true``."""
    if path.exists():
        return path
    message = f"{path} not present (shared data folder missing; set GEOMODEL_DATA)"
    if os.environ.get("CI") == "true":
        pytest.fail(message + " -- CI must run with the data")
    pytest.skip(message)
