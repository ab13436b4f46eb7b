"""``geomodel`` on PATH: the set-up writes a working command into the venv's ``bin/``.

The console script of ``setup.py`` lands in ``lib/geomodel_ros/`` (for ``ros2 run``), so
``.ci/setup_env.sh`` adds ``bin/geomodel`` with ``.ci/install_geomodel_command.sh``.  The
script is tested on a temporary ``bin/`` (runs, idempotent, leaves a foreign file alone),
and the venv's own command where the set-up has written it.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from geomodel_ros.core.params import PARAMETERS

ROOT = Path(__file__).resolve().parent.parent
INSTALL = ROOT / ".ci" / "install_geomodel_command.sh"
VENV_COMMAND = Path(sys.executable).with_name("geomodel")


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    return env


def _install(bin_dir: Path) -> subprocess.CompletedProcess:
    return subprocess.run(["bash", str(INSTALL), str(bin_dir), sys.executable],
                          capture_output=True, text=True, timeout=60)


def _check_params_output(command: Path, cwd: Path) -> None:
    proc = subprocess.run([str(command), "params"], cwd=cwd, env=_env(), capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    values = yaml.safe_load(proc.stdout)["modeler"]["ros__parameters"]
    assert {p.name for p in PARAMETERS} <= set(values)
    assert values["voxel_size"] == next(p.default for p in PARAMETERS if p.name == "voxel_size")


def test_installed_command_prints_the_parameters(tmp_path):
    proc = _install(tmp_path / "bin")
    assert proc.returncode == 0, proc.stderr
    command = tmp_path / "bin" / "geomodel"
    assert os.access(command, os.X_OK)
    _check_params_output(command, cwd=tmp_path)


def test_install_is_idempotent(tmp_path):
    assert _install(tmp_path / "bin").returncode == 0
    command = tmp_path / "bin" / "geomodel"
    first = command.read_text()
    stamp = command.stat().st_mtime_ns
    again = _install(tmp_path / "bin")
    assert again.returncode == 0 and again.stdout == ""  # nothing rewritten
    assert command.read_text() == first and command.stat().st_mtime_ns == stamp


def test_install_leaves_a_foreign_command_alone(tmp_path):
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    foreign = bin_dir / "geomodel"
    foreign.write_text("#!/bin/sh\necho someone else's geomodel\n")
    proc = _install(bin_dir)
    assert proc.returncode == 0 and "left as it is" in proc.stdout
    assert foreign.read_text() == "#!/bin/sh\necho someone else's geomodel\n"


def test_install_requires_both_arguments(tmp_path):
    proc = subprocess.run(["bash", str(INSTALL), str(tmp_path)], capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 2 and "usage" in proc.stderr
    assert not (tmp_path / "geomodel").exists()


def test_setup_writes_the_command_into_the_venv():
    assert 'install_geomodel_command.sh "$VENV/bin" "$VENV/bin/python"' in \
        (ROOT / ".ci" / "setup_env.sh").read_text()


@pytest.mark.skipif(not VENV_COMMAND.exists(),
                    reason=f"{VENV_COMMAND} not written yet: run `make setup`")
def test_venv_command_prints_the_parameters(tmp_path):
    _check_params_output(VENV_COMMAND, cwd=tmp_path)
