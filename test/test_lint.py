"""Lint as a test, as ROS 2 packages carry ament_flake8 / ament_pep257.

The rule set is ruff.toml's (pyflakes, pycodestyle, pep257 docstrings, unused arguments);
the whole tree must be clean.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _ruff() -> list[str]:
    exe = Path(sys.executable).with_name("ruff")
    if exe.exists():
        return [str(exe)]
    found = shutil.which("ruff")
    assert found, "ruff is not installed (it is pinned in .ci/requirements.txt: run make setup)"
    return [found]


def test_whole_tree_is_lint_clean():
    proc = subprocess.run([*_ruff(), "check", "--config", str(ROOT / "ruff.toml"),
                           "--output-format", "concise", "--no-cache", str(ROOT)],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr


def test_lint_catches_a_violation(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text('"""Module."""\n\nimport os\n\n\n'
                   'def f(unused):\n    """Return one."""\n    return 1\n')
    proc = subprocess.run([*_ruff(), "check", "--config", str(ROOT / "ruff.toml"),
                           "--output-format", "concise", "--no-cache", str(bad)],
                          capture_output=True, text=True)
    assert proc.returncode == 1
    assert "F401" in proc.stdout and "ARG001" in proc.stdout
