#!/usr/bin/env python3
"""Bring a clone to a working state: a .venv with the locked dependencies and the built interface package.

Idempotent and cheap when nothing changed: each stage records a fingerprint of its inputs in
``.venv/dynenv-bootstrap.json`` and is skipped while the fingerprint matches. Stdlib only, because it runs before
the venv exists.
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
VENV = ROOT / ".venv"
VENV_PYTHON = VENV / "bin" / "python"
STATE_FILE = VENV / "dynenv-bootstrap.json"
LOCK = ROOT / "requirements.lock"
MSG_SRC = ROOT / "msg_defs"
# Interface packages to build into the venv, dependencies first: upstream packages without a PyPI wheel (same
# definitions, same type hashes; msg_defs/upstream/README.md), then dynenv_msgs.
UPSTREAM_PACKAGES = ("tf2_msgs", "vision_msgs", "soccer_vision_attribute_msgs", "soccer_vision_3d_msgs",
                     "game_controller_spl_interfaces")
INTERFACE_PACKAGES = (*(MSG_SRC / "upstream" / name for name in UPSTREAM_PACKAGES), MSG_SRC)
BUILD = ROOT / "build"
REQUIRED_PYTHON = (3, 11)
# Paths of the machine that built the ROS wheels, hard-coded in their exported CMake targets (a known defect).
WHEEL_BUILD_PYTHON_INCLUDE = "/opt/python/cp311-cp311/include/python3.11"
WHEEL_BUILD_NUMPY_INCLUDE = "/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include"


class BootstrapError(RuntimeError):
    """A problem the user must fix; printed without a traceback."""


def log(message: str) -> None:
    print(f"[bootstrap] {message}", flush=True)


def fingerprint(*paths: Path, extra: str = "") -> str:
    digest = hashlib.sha256(extra.encode())
    for path in paths:
        files = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
        for file in files:
            digest.update(str(file.relative_to(ROOT)).encode())
            digest.update(file.read_bytes())
    return digest.hexdigest()


def find_python() -> str:
    """The interpreter for the venv: this one if it is 3.11, else python3.11 from PATH."""
    if sys.version_info[:2] == REQUIRED_PYTHON:
        return sys.executable
    candidate = shutil.which("python3.11")
    if candidate:
        return candidate
    raise BootstrapError(
        "Python 3.11 is required (the ROS 2 Jazzy wheels on PyPI are built for CPython 3.11) and "
        "`python3.11` is not on PATH. Install it, e.g. `apt-get install python3.11 python3.11-venv` "
        "or `pyenv install 3.11`.")


def check_prerequisites() -> None:
    missing = []
    for tool, hint in (("cmake", "cmake (>= 3.22)"), ("ninja", "ninja-build"), ("git", "git")):
        if shutil.which(tool) is None:
            missing.append(hint)
    if not any(shutil.which(cc) for cc in ("cc", "gcc", "clang")):
        missing.append("a C/C++ compiler (gcc/g++ or clang)")
    if missing:
        raise BootstrapError("missing prerequisites; please install: " + ", ".join(missing)
                             + " (Debian/Ubuntu: apt-get install cmake ninja-build build-essential git)")


def run(cmd: list[str], env: dict[str, str] | None = None, quiet_log: Path | None = None) -> None:
    """Run a command; on failure show its output (kept in a log file when quiet)."""
    if quiet_log is None:
        result = subprocess.run(cmd, env=env, cwd=ROOT)
    else:
        quiet_log.parent.mkdir(parents=True, exist_ok=True)
        with quiet_log.open("w") as handle:
            result = subprocess.run(cmd, env=env, cwd=ROOT, stdout=handle, stderr=subprocess.STDOUT)
        if result.returncode != 0:
            print(quiet_log.read_text()[-6000:], file=sys.stderr)
    if result.returncode != 0:
        raise BootstrapError(f"command failed ({result.returncode}): {' '.join(cmd)}"
                             + (f"; full log: {quiet_log}" if quiet_log else ""))


def load_state() -> dict[str, str]:
    try:
        return json.loads(STATE_FILE.read_text())
    except (OSError, ValueError):
        return {}


def save_state(state: dict[str, str]) -> None:
    tmp = STATE_FILE.with_suffix(".tmp")
    tmp.write_text(json.dumps(state, indent=1))
    os.replace(tmp, STATE_FILE)  # atomic: an interrupted bootstrap never leaves a half-written state


def ensure_venv(python: str) -> None:
    if VENV_PYTHON.exists():
        return
    log(f"creating {VENV.relative_to(ROOT)} with {python}")
    run([python, "-m", "venv", str(VENV)])


def install_dependencies(state: dict[str, str]) -> bool:
    key = fingerprint(LOCK, extra=sys.version)
    if state.get("dependencies") == key:
        return False
    log("installing locked dependencies (first run: about 2 minutes on an idle 2-core machine, up to 5 on a busy one)")
    run([str(VENV_PYTHON), "-m", "pip", "install", "--disable-pip-version-check", "--no-deps",
         "-r", str(LOCK)], quiet_log=ROOT / "build" / "logs" / "pip-install.log")
    state["dependencies"] = key
    state.pop("package", None)
    state.pop("interfaces", None)  # the message wheels may have been reinstalled: redo the CMake fix and build
    save_state(state)
    return True


def install_package(state: dict[str, str]) -> None:
    # The editable finder maps top-level packages found at install time: a new package needs a reinstall.
    packages = sorted(p.parent.name for p in ROOT.glob("*/__init__.py"))
    key = fingerprint(ROOT / "setup.py", ROOT / "setup.cfg", extra=state.get("dependencies", "") + str(packages))
    if state.get("package") == key:
        return
    log("installing dynenv_ros (editable)")
    run([str(VENV_PYTHON), "-m", "pip", "install", "--disable-pip-version-check", "--no-deps",
         "--no-build-isolation", "-e", str(ROOT)], quiet_log=ROOT / "build" / "logs" / "pip-editable.log")
    state["package"] = key
    save_state(state)


def venv_include_dirs() -> tuple[str, str]:
    probe = ("import numpy, sysconfig; print(sysconfig.get_paths()['include']); print(numpy.get_include())")
    out = subprocess.run([str(VENV_PYTHON), "-c", probe], check=True, capture_output=True, text=True).stdout
    python_include, numpy_include = out.split()
    return python_include, numpy_include


def fix_cmake_exports() -> int:
    """Point the wheels' exported CMake targets at this venv's Python and numpy headers (venv only)."""
    python_include, numpy_include = venv_include_dirs()
    if not Path(python_include, "Python.h").exists():
        raise BootstrapError(f"Python headers not found in {python_include}: install the Python 3.11 "
                             "development files (e.g. apt-get install python3.11-dev)")
    changed = 0
    for cmake_file in (VENV / "share").rglob("*.cmake"):
        text = cmake_file.read_text()
        if WHEEL_BUILD_PYTHON_INCLUDE not in text and WHEEL_BUILD_NUMPY_INCLUDE not in text:
            continue
        # numpy first: the python prefix is a prefix of the numpy path.
        text = text.replace(WHEEL_BUILD_NUMPY_INCLUDE, numpy_include)
        text = text.replace(WHEEL_BUILD_PYTHON_INCLUDE, python_include)
        cmake_file.write_text(text)
        changed += 1
    leftovers = [str(p) for p in (VENV / "share").rglob("*.cmake") if "/opt/python/cp311" in p.read_text()]
    if leftovers:
        raise BootstrapError(f"CMake exports still name the wheel build machine: {leftovers[:3]}")
    return changed


def build_interfaces(state: dict[str, str]) -> None:
    # The package list counts too: a package added to the list (its sources already there) is built.
    key = fingerprint(MSG_SRC, extra=state.get("dependencies", "") + str(UPSTREAM_PACKAGES))
    if state.get("interfaces") == key:
        return
    changed = fix_cmake_exports()
    log(f"building the interface packages into the venv (patched {changed} exported CMake files)")
    env = dict(os.environ, AMENT_PREFIX_PATH=str(VENV), CMAKE_PREFIX_PATH=str(VENV))
    logs = BUILD / "logs"
    for source in INTERFACE_PACKAGES:
        name = "msg_defs" if source == MSG_SRC else source.name
        build = BUILD / name
        shutil.rmtree(build, ignore_errors=True)
        run(["cmake", "-G", "Ninja", "-S", str(source), "-B", str(build), f"-DPython3_EXECUTABLE={VENV_PYTHON}",
             "-DBUILD_TESTING=OFF", f"-DCMAKE_INSTALL_PREFIX={VENV}"], env=env, quiet_log=logs / f"{name}-configure.log")
        run(["cmake", "--build", str(build)], env=env, quiet_log=logs / f"{name}-build.log")
        run(["cmake", "--install", str(build)], env=env, quiet_log=logs / f"{name}-install.log")
    state["interfaces"] = key
    save_state(state)


def main() -> int:
    try:
        check_prerequisites()
        python = find_python()
        ensure_venv(python)
        state = load_state()
        install_dependencies(state)
        install_package(state)
        build_interfaces(state)
    except BootstrapError as error:
        print(f"[bootstrap] error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("[bootstrap] interrupted; rerun to finish (completed stages are kept)", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
