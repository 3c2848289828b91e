"""Both packages are valid ROS 2 packages: catkin_pkg-valid format-3 manifests, ament_python layout, entry points."""
from __future__ import annotations

import configparser
import importlib
import re
from pathlib import Path

import pytest
from catkin_pkg.package import parse_package

REPO = Path(__file__).resolve().parent.parent


@pytest.mark.parametrize("folder, name, build_type", [(".", "dynenv_ros", "ament_python"),
                                                       ("msg_defs", "dynenv_msgs", "ament_cmake")])
def test_manifest_is_valid_format_3(folder, name, build_type):
    package = parse_package(REPO / folder / "package.xml")
    package.validate()  # raises InvalidPackage on any problem
    assert package.package_format == 3
    assert package.name == name
    assert package.get_build_type() == build_type


def test_interface_package_declares_what_rosidl_needs():
    package = parse_package(REPO / "msg_defs" / "package.xml")
    assert "rosidl_interface_packages" in [group.name for group in package.member_of_groups]
    buildtool = {d.name for d in package.buildtool_depends}
    assert {"ament_cmake", "rosidl_default_generators"} <= buildtool
    assert "rosidl_default_runtime" in {d.name for d in package.exec_depends}
    cmake = (REPO / "msg_defs" / "CMakeLists.txt").read_text()
    for kind in ("msg", "srv"):
        for path in (REPO / "msg_defs" / kind).glob(f"*.{kind}"):
            assert f'"{kind}/{path.name}"' in cmake, f"{path.name} is not generated"
    # Every message package used in a definition must be a declared dependency.
    used = set()
    for path in (REPO / "msg_defs").glob("*/*.*"):
        used |= set(re.findall(r"^\s*(\w+)/\w+", path.read_text(), re.MULTILINE))
    used.discard(package.name)        # its own types, named with the package (OperatorSignature in the services)
    declared = {d.name for d in package.build_depends} & {d.name for d in package.exec_depends}
    assert used <= declared


def test_ament_python_package_layout():
    assert (REPO / "resource" / "dynenv_ros").is_file()
    setup_cfg = configparser.ConfigParser()
    setup_cfg.read(REPO / "setup.cfg")
    assert setup_cfg["develop"]["script_dir"] == "$base/lib/dynenv_ros"
    assert setup_cfg["install"]["install_scripts"] == "$base/lib/dynenv_ros"
    setup_py = (REPO / "setup.py").read_text()
    assert '"share/ament_index/resource_index/packages"' in setup_py
    assert 'glob("config/*.yaml")' in setup_py and list((REPO / "config").glob("*.yaml"))
    run_depends = {d.name for d in parse_package(REPO / "package.xml").exec_depends}
    assert {"rclpy", "dynenv_msgs"} <= run_depends


def test_every_console_script_resolves_to_a_main():
    from importlib.metadata import entry_points

    scripts = {ep.name: ep for ep in entry_points(group="console_scripts") if ep.module.startswith(
        ("dynenv_ros", "policy_node", "benchmarks"))}
    assert {"selfcheck_talker", "selfcheck_listener", "dynenv-run", "dynenv-bench"} <= set(scripts)
    for entry in scripts.values():
        assert callable(getattr(importlib.import_module(entry.module), entry.attr))
