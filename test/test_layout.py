"""The core stays usable without ROS: importing it loads neither rclpy nor generated messages, nor torch (an
environment process must stay small). And the import graph keeps its layers: no import cycle between the packages
and modules named below (read from the source with ``ast``, function-level imports included)."""
from __future__ import annotations

import ast
import pkgutil
import subprocess
import sys
from pathlib import Path

import dynenv_ros.bags
import dynenv_ros.core
import dynenv_ros.envs
import dynenv_ros.evaluation
import dynenv_ros.perception
import dynenv_ros.render
import dynenv_ros.sim
import dynenv_ros.soccer

ROS_FREE_PACKAGES = [dynenv_ros.core, dynenv_ros.bags, dynenv_ros.sim, dynenv_ros.soccer, dynenv_ros.envs,
                     dynenv_ros.render, dynenv_ros.perception, dynenv_ros.evaluation]


def test_ros_free_packages_import_no_ros():
    modules = [f"{pkg.__name__}.{info.name}" for pkg in ROS_FREE_PACKAGES
               for info in pkgutil.iter_modules(pkg.__path__)]
    assert modules, "no modules found to check"
    probe = (f"import sys\nfor m in {modules!r}: __import__(m)\n"
             "bad = sorted(m for m in sys.modules if m.split('.')[0] in ('rclpy', 'dynenv_msgs', 'rosidl_parser', 'torch'))\n"
             "print(bad)")
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "[]", result.stdout


# -- import graph ----------------------------------------------------------------------------------------------------
PACKAGE_ROOT = Path(dynenv_ros.__file__).resolve().parents[1]      # the folder holding dynenv_ros/


def imported_modules(path: Path) -> set[str]:
    """Every module a source file imports, at module level or inside a function (lazy imports count): ``import a.b``
    gives ``a.b``; ``from a import b`` gives ``a`` and ``a.b`` (b may be a submodule); relative imports resolved."""
    module = ".".join(path.relative_to(PACKAGE_ROOT).with_suffix("").parts)
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parent = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                base = f"{parent}.{base}" if base else parent
            found.add(base)
            found.update(f"{base}.{alias.name}" for alias in node.names)
    return found


def _imports(importer: str, imported: str) -> list[str]:
    """The files of module or package ``importer`` that import ``imported`` or anything inside it."""
    path = PACKAGE_ROOT.joinpath(*importer.split("."))
    files = sorted(path.rglob("*.py")) if path.is_dir() else [path.with_suffix(".py")]
    assert files and all(f.is_file() for f in files), f"no source for {importer}"
    return [str(f.relative_to(PACKAGE_ROOT)) for f in files
            if any(m == imported or m.startswith(imported + ".") for m in imported_modules(f))]


def test_render_detections_and_driving_do_not_import_each_other():
    # The scenario-neutral overlay (detections) takes its colours from topdown; the driving pictures may use the
    # overlay (one direction, lazily), never the other way round.
    assert _imports("dynenv_ros.render.detections", "dynenv_ros.render.driving") == []
    assert not (_imports("dynenv_ros.render.driving", "dynenv_ros.render.detections")
                and _imports("dynenv_ros.render.detections", "dynenv_ros.render.driving"))


def test_learning_never_imports_evaluation():
    # evaluation -> learning (a training checkpoint's policy, through learning.agents) is the one direction: the
    # trainer, the opponents and the rest of learning import nothing of dynenv_ros.evaluation, not even lazily.
    assert _imports("dynenv_ros.learning", "dynenv_ros.evaluation") == []
    assert _imports("dynenv_ros.evaluation", "dynenv_ros.learning"), "expected evaluation to use learning.agents"
    # and evaluation loads a checkpoint without the trainer
    assert _imports("dynenv_ros.evaluation", "dynenv_ros.learning.trainer") == []


def test_evaluation_modules_have_no_import_cycle():
    folder = PACKAGE_ROOT / "dynenv_ros" / "evaluation"
    modules = {f"dynenv_ros.evaluation.{f.stem}": f for f in folder.glob("*.py") if f.stem != "__init__"}
    graph = {name: {m for m in imported_modules(path) if m in modules and m != name} for name, path in modules.items()}
    done: set[str] = set()

    def visit(name: str, path: tuple[str, ...]) -> None:
        assert name not in path, f"import cycle: {' -> '.join(path + (name,))}"
        if name not in done:
            for other in sorted(graph[name]):
                visit(other, path + (name,))
            done.add(name)

    for name in sorted(graph):
        visit(name, ())


RAY_MODULES = {"dynenv_ros/learning/ray_connection.py", "dynenv_ros/learning/ray_pool.py",
               "dynenv_ros/experiments/sweep.py"}


def test_only_the_ray_modules_import_ray():
    # Ray is a training dependency: the simulator, the agent, the ROS graph and the in-process trainer run without it
    users = set()
    for package in ("dynenv_ros", "policy_node"):
        users.update(_imports(package, "ray"))
    assert users == RAY_MODULES


def test_the_trainer_and_the_ros_graph_import_without_ray():
    probe = ("import sys\nimport dynenv_ros.learning.trainer, dynenv_ros.learning.async_trainer, "
             "dynenv_ros.learning.train_cli, dynenv_ros.nodes.trainer_node, dynenv_ros.nodes.sim_node\n"
             "print(sorted(m for m in sys.modules if m.split('.')[0] == 'ray'))")
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "[]", result.stdout
