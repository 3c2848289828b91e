"""The core stays usable without ROS: importing it loads neither rclpy nor generated messages, nor torch (an
environment process must stay small)."""
from __future__ import annotations

import pkgutil
import subprocess
import sys

import dynenv_ros.bags
import dynenv_ros.core
import dynenv_ros.envs
import dynenv_ros.perception
import dynenv_ros.render
import dynenv_ros.sim
import dynenv_ros.soccer

ROS_FREE_PACKAGES = [dynenv_ros.core, dynenv_ros.bags, dynenv_ros.sim, dynenv_ros.soccer, dynenv_ros.envs,
                     dynenv_ros.render, dynenv_ros.perception]


def test_ros_free_packages_import_no_ros():
    modules = [f"{pkg.__name__}.{info.name}" for pkg in ROS_FREE_PACKAGES
               for info in pkgutil.iter_modules(pkg.__path__)]
    assert modules, "no modules found to check"
    probe = (f"import sys\nfor m in {modules!r}: __import__(m)\n"
             "bad = sorted(m for m in sys.modules if m.split('.')[0] in ('rclpy', 'dynenv_msgs', 'rosidl_parser', 'torch'))\n"
             "print(bad)")
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "[]", result.stdout
