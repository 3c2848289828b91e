"""package.xml declares every dependency the code imports (rosdep keys where rosdistro has them) and nothing else, and
setup.py names every Python dependency for pip, so that `rosdep install` / `pip install .` leave no node failing at
import (issue 28). The imports are read from the source with ``ast`` (lazy imports inside functions count); the
mapping from an imported module to its package.xml key and pip distribution is the explicit table below: a new
import fails here until it is added to the table, package.xml and setup.py.
"""
from __future__ import annotations

import ast
import importlib.metadata
import re
import sys
from pathlib import Path

import pytest
from catkin_pkg.package import parse_package

REPO = Path(__file__).resolve().parent.parent
PACKAGE_DIRS = ("dynenv_ros", "policy_node", "benchmarks", "launch")   # what setup.py installs (launch: share)
OWN = {"dynenv_ros", "policy_node", "benchmarks"}

# ROS packages imported as Python modules: the package.xml key is the package's own name.
ROS_PACKAGES = {"rclpy", "rcl_interfaces", "rosidl_parser", "ament_index_python", "builtin_interfaces", "std_msgs",
                "geometry_msgs", "rosgraph_msgs", "sensor_msgs", "visualization_msgs", "diagnostic_msgs",
                "tf2_msgs", "vision_msgs", "soccer_vision_3d_msgs", "game_controller_spl_interfaces", "dynenv_msgs",
                "launch", "launch_ros"}
# Python modules: (rosdep key from rosdistro's rosdep/python.yaml or None where it has none, pip distribution).
PYTHON_MODULES: dict[str, tuple[str | None, str]] = {
    "numpy": ("python3-numpy", "numpy"),
    "yaml": ("python3-yaml", "PyYAML"),
    "scipy": ("python3-scipy", "scipy"),
    "torch": ("python3-torch", "torch"),
    "numba": ("python3-numba", "numba"),
    "PIL": ("python3-pil", "pillow"),
    "matplotlib": ("python3-matplotlib", "matplotlib"),
    "tqdm": ("python3-tqdm", "tqdm"),
    "cryptography": ("python3-cryptography", "cryptography"),
    "gymnasium": ("python3-gymnasium-pip", "gymnasium"),
    "rosbags": ("python3-rosbags-pip", "rosbags"),
    "onnxruntime": ("python3-onnxruntime-pip", "onnxruntime"),
    "pymunk": (None, "pymunk"),
    "pettingzoo": (None, "pettingzoo"),
    "safetensors": (None, "safetensors"),
    "onnx": (None, "onnx"),
    "foxglove": (None, "foxglove-sdk"),
}
# Imported lazily by training and evaluation tools only: setup.py's "train" extra, not package.xml.
TRAINING_MODULES = {"ray": "ray", "pymc": "pymc"}
# Needed through another package's API rather than imported by name: (key or None, distribution, the code's use).
INDIRECT = {
    "tensorboard": ("python3-tensorboard-pip", "tensorboard", "torch.utils.tensorboard"),
    "onnxscript": (None, "onnxscript", "torch.onnx.export"),
}
# Imported by name but installed by a declared dependency: module → (the dependency, its distribution).
TRANSITIVE = {"backports": ("rosbags", "backports.zstd"), "lz4": ("rosbags", "lz4")}
# Test-only imports: module → (test_depend key or None, pip distribution of setup.py's "test" extra).
TEST_MODULES: dict[str, tuple[str | None, str]] = {
    "pytest": ("python3-pytest", "pytest"),
    "catkin_pkg": ("python3-catkin-pkg", "catkin-pkg"),
    "stable_baselines3": ("python3-stable-baselines3-pip", "stable-baselines3"),
    "supersuit": (None, "supersuit"),
    "websockets": ("python3-websockets", "websockets"),
    "google": ("python3-protobuf", "protobuf"),        # test_live_view_server decodes the live view's protobuf
}
# Test tools used without an import: key or distribution → the evidence in the repository.
TEST_TOOLS = {"python3-pytest-xdist": ("Makefile", "pytest -n 2"), "pytest-xdist": ("Makefile", "pytest -n 2"),
              "colcon-core": ("test/test_colcon_build.py", '"colcon"'),
              "colcon-ros": ("test/test_colcon_build.py", '"colcon"'),
              "colcon-package-selection": ("test/test_colcon_build.py", '"--base-paths"')}


def imported_top_level(paths: list[Path]) -> dict[str, set[str]]:
    """Top-level module → files importing it (absolute imports, module level or inside functions)."""
    found: dict[str, set[str]] = {}
    for path in paths:
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module] if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module
                     else [])
            for name in names:
                found.setdefault(name.split(".")[0], set()).add(str(path.relative_to(REPO)))
    return found


def third_party(found: dict[str, set[str]], local: set[str] = frozenset()) -> dict[str, set[str]]:
    return {m: f for m, f in found.items() if m not in sys.stdlib_module_names and m not in OWN and m not in local}


def package_files() -> list[Path]:
    return [p for d in PACKAGE_DIRS for p in sorted((REPO / d).rglob("*.py"))]


def normalise(distribution: str) -> str:
    return re.sub(r"[-_.]+", "-", distribution).lower()


def distribution_name(requirement: str) -> str:
    return normalise(re.split(r"[<>=!~;\[ ]", requirement, maxsplit=1)[0])


def setup_lists() -> tuple[list[str], dict[str, list[str]]]:
    """INSTALL_REQUIRES and EXTRAS_REQUIRE, read from setup.py without running it."""
    values = {}
    for node in ast.parse((REPO / "setup.py").read_text()).body:
        if isinstance(node, ast.Assign) and len(node.targets) == 1 and isinstance(node.targets[0], ast.Name):
            if node.targets[0].id in ("INSTALL_REQUIRES", "EXTRAS_REQUIRE"):
                values[node.targets[0].id] = ast.literal_eval(node.value)
    return values["INSTALL_REQUIRES"], values["EXTRAS_REQUIRE"]


@pytest.fixture(scope="module")
def manifest():
    return parse_package(REPO / "package.xml")


@pytest.fixture(scope="module")
def runtime_imports() -> dict[str, set[str]]:
    return third_party(imported_top_level(package_files()))


def test_every_import_of_the_package_is_in_the_table(runtime_imports):
    known = ROS_PACKAGES | set(PYTHON_MODULES) | set(TRAINING_MODULES) | set(TRANSITIVE)
    unknown = {m: sorted(f)[:3] for m, f in runtime_imports.items() if m not in known}
    assert not unknown, f"imports missing from this test's table (and perhaps package.xml / setup.py): {unknown}"
    unused = sorted((ROS_PACKAGES | set(PYTHON_MODULES) | set(TRAINING_MODULES) | set(TRANSITIVE))
                    - set(runtime_imports))
    assert not unused, f"table entries the code no longer imports: {unused}"


def test_package_xml_declares_every_imported_package_and_nothing_else(manifest, runtime_imports):
    runtime = {d.name for d in manifest.exec_depends} | {d.name for d in manifest.run_depends}
    expected = ({m for m in runtime_imports if m in ROS_PACKAGES}
                | {key for m, (key, _) in PYTHON_MODULES.items() if key and m in runtime_imports}
                | {key for key, _, _ in INDIRECT.values() if key})
    assert sorted(expected - runtime) == [], "imported but not declared (exec_depend)"
    assert sorted(runtime - expected) == [], "declared (exec_depend) but not imported"


def test_dependencies_without_a_rosdep_key_are_named_in_package_xml(runtime_imports):
    """rosdep cannot install them: package.xml's comment and the README say they come from pip."""
    text = (REPO / "package.xml").read_text()
    readme = (REPO / "README.md").read_text()
    keyless = ([d for m, (key, d) in PYTHON_MODULES.items() if key is None]
               + [d for key, d, _ in INDIRECT.values() if key is None] + list(TRAINING_MODULES.values()))
    assert [d for d in keyless if d not in text] == []
    assert [d for d in keyless if f"`{d}`" not in readme] == []


def test_indirect_and_transitive_dependencies_are_real():
    sources = "\n".join(p.read_text() for p in package_files())
    for distribution, (_, _, use) in INDIRECT.items():
        assert use in sources, f"{distribution} is declared for {use}, which the code no longer uses"
    for module, (owner, distribution) in TRANSITIVE.items():
        requires = {distribution_name(r) for r in importlib.metadata.requires(owner) or []}
        assert normalise(distribution) in requires, f"{owner} no longer brings {distribution} ({module})"


def test_setup_py_installs_the_python_dependencies_and_extras(runtime_imports):
    install_requires, extras = setup_lists()
    runtime = {distribution_name(r) for r in install_requires}
    expected = ({normalise(d) for m, (_, d) in PYTHON_MODULES.items() if m in runtime_imports}
                | {normalise(d) for _, d, _ in INDIRECT.values()})
    assert sorted(expected - runtime) == [], "imported but not in install_requires"
    assert sorted(runtime - expected) == [], "in install_requires but not imported"
    assert {distribution_name(r) for r in extras["train"]} == {normalise(d) for d in TRAINING_MODULES.values()}
    assert not runtime & {distribution_name(r) for r in extras["train"]}


def test_torch_is_never_pinned_to_a_build_and_bootstrap_ignores_install_requires():
    """install_requires must not change what `make bootstrap` installs: bootstrap installs requirements.lock and the
    package itself with --no-deps; and torch gets a lower bound only (the CPU wheel is the lock's business)."""
    install_requires, _ = setup_lists()
    torch = [r for r in install_requires if distribution_name(r) == "torch"]
    assert torch and all("+" not in r and "==" not in r for r in torch)
    bootstrap = (REPO / "tools" / "bootstrap.py").read_text()
    pip_calls = re.findall(r'"pip", "install".*?\]', bootstrap, re.DOTALL)
    assert len(pip_calls) == 2 and all('"--no-deps"' in call for call in pip_calls), pip_calls
    lock = {normalise(line.split("==")[0]) for line in (REPO / "requirements.lock").read_text().splitlines()
            if "==" in line and not line.startswith("#")}
    _, extras = setup_lists()
    everything = [*install_requires, *(r for reqs in extras.values() for r in reqs)]
    assert sorted(d for d in map(distribution_name, everything) if d not in lock) == [], \
        "setup.py names a distribution the lock (what bootstrap installs and the tests run with) lacks"


def test_test_dependencies_are_declared(manifest):
    local = {p.stem for p in (REPO / "test").glob("*.py")}
    imports = third_party(imported_top_level(sorted((REPO / "test").glob("*.py"))), local)
    runtime_modules = ROS_PACKAGES | set(PYTHON_MODULES) | set(TRAINING_MODULES) | set(TRANSITIVE)
    unknown = sorted(m for m in imports if m not in runtime_modules and m not in TEST_MODULES)
    assert unknown == [], "test imports missing from TEST_MODULES (and package.xml's test_depend / the test extra)"
    declared = {d.name for d in manifest.test_depends}
    keys = {key for key, _ in TEST_MODULES.values() if key}
    tools = {key for key in TEST_TOOLS if key.startswith("python3-")}
    assert sorted(declared ^ (keys | tools)) == []
    _, extras = setup_lists()
    test_extra = {distribution_name(r) for r in extras["test"]}
    assert test_extra == {normalise(d) for _, d in TEST_MODULES.values()} | {
        normalise(k) for k in TEST_TOOLS if not k.startswith("python3-")}
    for _, (path, evidence) in TEST_TOOLS.items():
        assert evidence in (REPO / path).read_text()


def test_interface_package_depends_on_exactly_what_its_definitions_use():
    package = parse_package(REPO / "msg_defs" / "package.xml")
    used = set()
    for path in sorted((REPO / "msg_defs" / "msg").glob("*.msg")) + sorted((REPO / "msg_defs" / "srv").glob("*.srv")):
        used |= set(re.findall(r"^\s*(\w+)/\w+", path.read_text(), re.MULTILINE))
    used.discard(package.name)        # its own types, named with the package (OperatorSignature in the services)
    both = {d.name for d in package.build_depends} & {d.name for d in package.exec_depends}
    assert both == used
    cmake = (REPO / "msg_defs" / "CMakeLists.txt").read_text()
    found = set(re.findall(r"find_package\((\w+) REQUIRED\)", cmake)) - {"ament_cmake", "rosidl_default_generators"}
    assert found == used
    dependencies = re.search(r"DEPENDENCIES ([\w ]+)", cmake)
    assert dependencies and set(dependencies.group(1).split()) == used
