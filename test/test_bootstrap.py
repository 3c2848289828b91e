"""The set-up script: idempotent, clear about missing prerequisites, and fixes the wheels' CMake exports."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy
import pytest
from tool_scripts import load_tool

REPO = Path(__file__).resolve().parent.parent
BOOTSTRAP = REPO / "tools" / "bootstrap.py"
HOST_PYTHON = shutil.which("python3.11") or sys.executable


def load_bootstrap():
    return load_tool("bootstrap")


def test_second_run_with_nothing_changed_does_nothing():
    result = subprocess.run([HOST_PYTHON, str(BOOTSTRAP)], capture_output=True, text=True, cwd=REPO)
    assert result.returncode == 0, result.stderr
    assert result.stdout == "", f"bootstrap redid work: {result.stdout}"


def test_missing_prerequisite_is_named(tmp_path):
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    for tool in ("git", "gcc", "ninja"):  # everything but cmake
        os.symlink(shutil.which(tool), bin_dir / tool)
    env = dict(os.environ, PATH=str(bin_dir))
    # The venv's base interpreter itself, not a wrapper (a pyenv shim needs bash on PATH).
    result = subprocess.run([sys._base_executable, str(BOOTSTRAP)], capture_output=True, text=True, env=env,
                            cwd=REPO)
    assert result.returncode == 2
    assert "missing prerequisites" in result.stderr and "cmake" in result.stderr


def test_cmake_export_fix_rewrites_only_the_wheel_build_paths(tmp_path, monkeypatch):
    bootstrap = load_bootstrap()
    venv = tmp_path / "venv"
    export = venv / "share" / "std_msgs" / "cmake" / "export_std_msgs__rosidl_generator_pyExport.cmake"
    export.parent.mkdir(parents=True)
    export.write_text('INTERFACE_INCLUDE_DIRECTORIES "/opt/python/cp311-cp311/include/python3.11;'
                      '/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include;/keep/me"\n')
    untouched = venv / "share" / "other" / "other.cmake"
    untouched.parent.mkdir(parents=True)
    untouched.write_text("set(X /opt/elsewhere)\n")
    monkeypatch.setattr(bootstrap, "VENV", venv)
    monkeypatch.setattr(bootstrap, "VENV_PYTHON", Path(sys.executable))
    assert bootstrap.fix_cmake_exports() == 1
    text = export.read_text()
    assert "/opt/python" not in text and "/keep/me" in text and numpy.get_include() in text
    assert untouched.read_text() == "set(X /opt/elsewhere)\n"
    assert bootstrap.fix_cmake_exports() == 0  # idempotent


def test_fingerprint_follows_content(tmp_path, monkeypatch):
    bootstrap = load_bootstrap()
    monkeypatch.setattr(bootstrap, "ROOT", tmp_path)
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "x.msg").write_text("int32 x\n")
    first = bootstrap.fingerprint(tmp_path / "a")
    assert bootstrap.fingerprint(tmp_path / "a") == first
    (tmp_path / "a" / "x.msg").write_text("int64 x\n")
    assert bootstrap.fingerprint(tmp_path / "a") != first


def test_lock_pins_every_distribution_exactly():
    lines = [line for line in (REPO / "requirements.lock").read_text().splitlines()
             if line and not line.startswith("#")]
    assert lines and all("==" in line for line in lines)
    names = {line.split("==")[0].lower() for line in lines}
    assert {"torch", "pymunk", "numpy", "rosbags", "ros-jazzy-rclpy", "pytest", "pytest-xdist"} <= names
    assert next(line for line in lines if line.lower().startswith("torch==")).startswith("torch==2.13.0")
    from importlib.metadata import version
    for line in lines:  # the venv holds exactly what the lock says
        name, pinned = line.split("==")
        assert version(name) == pinned, name


def test_wrong_python_is_refused_with_instructions(tmp_path, monkeypatch):
    bootstrap = load_bootstrap()
    fake_sys = type("OtherPython", (), {"version_info": (3, 12, 0), "executable": "/usr/bin/python3.12"})
    monkeypatch.setattr(bootstrap, "sys", fake_sys)
    monkeypatch.setenv("PATH", str(tmp_path))  # no python3.11 to fall back on
    with pytest.raises(bootstrap.BootstrapError, match="Python 3.11 is required"):
        bootstrap.find_python()
