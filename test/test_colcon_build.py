"""Both packages build in an ordinary colcon workspace, and `ros2 run` finds the nodes where colcon installs them.

The ROS 2 Jazzy underlay here is the project venv (AMENT_PREFIX_PATH / CMAKE_PREFIX_PATH point at it), as a
system install would be on a robot. colcon does not look for packages inside another package's folder, so the
workspace names both package paths (docs/setup.md says the same to users).
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent


def copy_working_tree(destination: Path) -> None:
    files = subprocess.run(["git", "ls-files", "--cached", "--others", "--exclude-standard", "-z"], cwd=REPO,
                           capture_output=True, check=True).stdout.decode().split("\0")
    for name in filter(None, files):
        source = REPO / name
        if source.is_file():
            target = destination / name
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(source, target)


@pytest.mark.ros   # it runs the installed selfcheck_talker, which loads rclpy
def test_colcon_builds_both_packages_into_a_ros_layout(tmp_path):
    source = tmp_path / "src" / "dynenv_ros"
    copy_working_tree(source)
    venv = Path(sys.prefix)
    env = dict(os.environ, AMENT_PREFIX_PATH=str(venv), CMAKE_PREFIX_PATH=str(venv),
               PATH=f"{venv / 'bin'}{os.pathsep}{os.environ['PATH']}")
    result = subprocess.run(
        [str(venv / "bin" / "colcon"), "build", "--base-paths", str(source), str(source / "msg_defs"),
         "--cmake-args", "-DBUILD_TESTING=OFF", f"-DPython3_EXECUTABLE={sys.executable}", "-G", "Ninja"],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    install = tmp_path / "install"
    for node in ("selfcheck_talker", "selfcheck_listener", "sim_node", "scripted_policy", "policy_node", "recorder",
                 "bag_player"):
        assert os.access(install / "dynenv_ros" / "lib" / "dynenv_ros" / node, os.X_OK), node
    assert (install / "dynenv_ros" / "share" / "dynenv_ros" / "config" / "main_job.yaml").is_file()
    for preset in ("realistic", "dynenv", "none"):
        assert (install / "dynenv_ros" / "share" / "dynenv_ros" / "config" / "perception" / f"{preset}.yaml").is_file()
    assert (install / "dynenv_ros" / "share" / "ament_index" / "resource_index" / "packages" / "dynenv_ros").exists()
    assert (install / "dynenv_msgs" / "share" / "dynenv_msgs" / "msg" / "DetectionArray.msg").is_file()
    # The installed node script runs the installed code: a refused parameter proves it got as far as the node.
    site = next((install / "dynenv_ros" / "lib").glob("python3*/site-packages"))
    msgs_site = next((install / "dynenv_msgs" / "lib").glob("python3*/site-packages"))
    run_env = dict(os.environ, PYTHONPATH=f"{site}{os.pathsep}{msgs_site}")
    ran = subprocess.run([str(install / "dynenv_ros" / "lib" / "dynenv_ros" / "selfcheck_talker"), "--ros-args",
                          "-p", "samples_per_type:=0"], env=run_env, capture_output=True, text=True, timeout=60)
    assert ran.returncode == 2 and "samples_per_type" in ran.stderr, ran.stderr
