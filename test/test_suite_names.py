"""A module's tests are found from its name (issue 40, part 6; docs/setup.md#tests).

The rule: the module ``<package>/.../<folder>/<name>.py`` (every ``.py`` under dynenv_ros/ and policy_node/ but
``__init__.py``) is found when test/ holds ``test_<name>.py``, ``test_<name>_<anything>.py`` or
``test_<folder>_<name><anything>.py``, where ``<folder>`` is the folder the module is in: dynenv_ros/agent/export.py
is found by test_agent_export.py, dynenv_ros/envs/driving_v0.py by test_driving_v0.py, policy_node/periods.py by
test_periods.py or test_policy_node_periods.py. Only the nearest folder counts (test_learning_advantages.py would not
find dynenv_ros/learning/algo/advantages.py; test_algo_advantages.py does). A name alone can mislead (test_soccer_*.py
are not all about evaluation/soccer.py), so a file found by name counts only if it reaches the module: imports it, or
names it as ``python -m`` does, directly or through the repository's own imports (those inside functions too: the code
a test runs loads them; test/ros_marking.py reads the imports).

A module whose tests are in a file named after something else (the graph it runs in, the command that drives it, the
package whose test exercises its parts) is listed in ``COVERED_BY`` with that file, which must reach it: an entry
cannot outlive its test file or its module, and one whose module has since got a test found by name must go. A
module that no test exercises is in ``WITHOUT_TEST`` with the reason, so that the gap stays in sight.
"""
from __future__ import annotations

import ast
import functools
import re
from pathlib import Path

import pytest

import ros_marking

TEST_DIR = Path(__file__).resolve().parent
REPO = TEST_DIR.parent
PACKAGES = ("dynenv_ros", "policy_node")

COVERED_BY = {
    "dynenv_ros/agent/inputs.py": "test_padded_layout.py",
    "dynenv_ros/bags/inspect.py": "test_bags.py",
    "dynenv_ros/bags/mcap.py": "test_bags_recovery.py",
    "dynenv_ros/bags/qos.py": "test_bag_qos.py",
    "dynenv_ros/bags/recording.py": "test_recorder_faults.py",
    "dynenv_ros/bags/typestore.py": "test_interfaces_cdr.py",
    "dynenv_ros/bags/writer.py": "test_bags.py",
    "dynenv_ros/core/revision.py": "test_run_checkpoints.py",
    "dynenv_ros/core/shared_arrays.py": "test_core_settings.py",
    "dynenv_ros/core/writable.py": "test_train_disk.py",
    "dynenv_ros/driving/agent_actions.py": "test_driving_agent.py",
    "dynenv_ros/driving/pedestrians.py": "test_driving_world.py",
    "dynenv_ros/envs/action_gate.py": "test_sim_game.py",
    "dynenv_ros/envs/detection_messages.py": "test_padded_layout.py",
    "dynenv_ros/envs/driving_session.py": "test_sim_node_driving.py",
    "dynenv_ros/envs/parallel_agents.py": "test_robocup_v0.py",
    "dynenv_ros/envs/play.py": "test_soccer_ground_truth.py",
    "dynenv_ros/envs/pose_messages.py": "test_localization_ros.py",
    "dynenv_ros/envs/sb3_time_limit.py": "test_rl_libraries.py",
    "dynenv_ros/envs/session.py": "test_soccer_session.py",
    "dynenv_ros/envs/soccer_observations.py": "test_robocup_v0.py",
    "dynenv_ros/envs/soccer_spaces.py": "test_robocup_v0.py",
    "dynenv_ros/envs/teacher.py": "test_learning_teacher.py",
    "dynenv_ros/evaluation/cli.py": "test_evaluation_soccer.py",
    "dynenv_ros/evaluation/episodes.py": "test_evaluation_soccer.py",
    "dynenv_ros/evaluation/head_to_head.py": "test_evaluation_splits.py",
    "dynenv_ros/evaluation/ledger.py": "test_evaluation_splits.py",
    "dynenv_ros/evaluation/ratios.py": "test_evaluation_splits.py",
    "dynenv_ros/evaluation/results.py": "test_evaluation_soccer.py",
    "dynenv_ros/gamecontroller/robot_view.py": "test_ros_sports_input.py",
    "dynenv_ros/gamecontroller/udp.py": "test_ros_sports_graph.py",
    "dynenv_ros/graph/inventory_table.py": "test_inventory.py",
    "dynenv_ros/graph/process_graph.py": "test_main_job.py",
    "dynenv_ros/graph/train_graph.py": "test_main_job.py",
    "dynenv_ros/learning/algo/auxiliary.py": "test_learning_teacher.py",
    "dynenv_ros/learning/algo/experience.py": "test_algo_loop.py",
    "dynenv_ros/learning/algo/networks.py": "test_learning_update.py",
    "dynenv_ros/learning/distributed/child_process.py": "test_async_trainer.py",
    "dynenv_ros/learning/distributed/pool_source.py": "test_async_trainer.py",
    "dynenv_ros/learning/distributed/ray_connection.py": "test_ray_cluster.py",
    "dynenv_ros/learning/distributed/ray_pool.py": "test_ray_cluster.py",
    "dynenv_ros/learning/distributed/rollout_transfer.py": "test_async_trainer.py",
    "dynenv_ros/learning/distributed/rollout_worker.py": "test_async_trainer.py",
    "dynenv_ros/learning/distributed/shared_weights.py": "test_async_trainer.py",
    "dynenv_ros/learning/distributed/worker_pool.py": "test_async_trainer.py",
    "dynenv_ros/learning/messages/scenarios.py": "test_messages_assembly_driving.py",
    "dynenv_ros/learning/pretrain/data.py": "test_pretrain_cli.py",
    "dynenv_ros/learning/pretrain/evaluate.py": "test_pretrain_cli.py",
    "dynenv_ros/learning/pretrain/model.py": "test_pretrain_cli.py",
    "dynenv_ros/learning/pretrain/train.py": "test_pretrain_cli.py",
    "dynenv_ros/learning/resources.py": "test_async_trainer.py",
    "dynenv_ros/learning/run/disk_budget.py": "test_train_disk.py",
    "dynenv_ros/learning/run/metrics.py": "test_train_cli.py",
    "dynenv_ros/learning/sampling/acting.py": "test_inference_server.py",
    "dynenv_ros/learning/sampling/collector.py": "test_learning_update.py",
    "dynenv_ros/learning/sampling/in_process.py": "test_train_cli.py",
    "dynenv_ros/learning/sampling/opponents.py": "test_league.py",
    "dynenv_ros/learning/sampling/worlds.py": "test_async_trainer.py",
    "dynenv_ros/learning/trainer.py": "test_train_cli.py",
    "dynenv_ros/live_view/scene.py": "test_live_view_server.py",
    "dynenv_ros/nodes/bag_player.py": "test_bags.py",
    "dynenv_ros/nodes/motion_emulator.py": "test_ros_sports_graph.py",
    "dynenv_ros/nodes/selfcheck_listener.py": "test_main_job.py",
    "dynenv_ros/nodes/selfcheck_talker.py": "test_interfaces_subprocess.py",
    "dynenv_ros/nodes/trainer_parameters.py": "test_trainer_node.py",
    "dynenv_ros/perception/audit.py": "test_perception_leaks.py",
    "dynenv_ros/perception/detections.py": "test_perception_row_kernels.py",
    "dynenv_ros/perception/driving_kernels.py": "test_perception_driving_model.py",
    "dynenv_ros/perception/driving_params.py": "test_perception_driving_model.py",
    "dynenv_ros/perception/params.py": "test_perception_model.py",
    "dynenv_ros/perception/scene.py": "test_perception_geometry.py",
    "dynenv_ros/perception/soccer_kernels.py": "test_perception_geometry.py",
    "dynenv_ros/render/replay.py": "test_bags.py",
    "dynenv_ros/ros/action_inbox.py": "test_sim_node_faults.py",
    "dynenv_ros/ros/authentication.py": "test_action_auth_graph.py",
    "dynenv_ros/ros/conversions.py": "test_cdr_fast_path.py",
    "dynenv_ros/ros/dds_profiles.py": "test_weights_attacks.py",
    "dynenv_ros/ros/drain.py": "test_sim_node_faults.py",
    "dynenv_ros/ros/driving_markers.py": "test_sim_node_driving.py",
    "dynenv_ros/ros/experience_readers.py": "test_trainer_node.py",
    "dynenv_ros/ros/frame_parts.py": "test_ros_sports_input.py",
    "dynenv_ros/ros/frame_tags.py": "test_frame_auth_graph.py",
    "dynenv_ros/ros/keys_cli.py": "test_weights_signing.py",
    "dynenv_ros/ros/message_classes.py": "test_bags.py",
    "dynenv_ros/ros/node_runner.py": "test_sim_node_faults.py",
    "dynenv_ros/ros/operator_gate.py": "test_operator_attacks.py",
    "dynenv_ros/ros/parameters.py": "test_sim_node.py",
    "dynenv_ros/ros/pose_estimates.py": "test_localization_ros.py",
    "dynenv_ros/ros/qos.py": "test_sim_node_faults.py",
    "dynenv_ros/ros/ros_sports_conversion.py": "test_ros_sports_interfaces.py",
    "dynenv_ros/ros/selfcheck.py": "test_interfaces_subprocess.py",
    "dynenv_ros/ros/service_call.py": "test_doc_commands.py",
    "dynenv_ros/ros/signal_runner.py": "test_bags.py",
    "dynenv_ros/ros/sim_diagnostics.py": "test_sim_node_faults.py",
    "dynenv_ros/ros/sim_graph.py": "test_sim_node_faults.py",
    "dynenv_ros/ros/sim_outlet.py": "test_sim_node_faults.py",
    "dynenv_ros/ros/sim_parameters.py": "test_sim_node.py",
    "dynenv_ros/ros/sim_robot_io.py": "test_ros_sports_graph.py",
    "dynenv_ros/ros/topics.py": "test_sim_node.py",
    "dynenv_ros/ros/weights_follower.py": "test_weights_attacks.py",
    "dynenv_ros/ros/weights_release.py": "test_policy_weights.py",
    "dynenv_ros/scenarios/base.py": "test_scenarios_registry.py",
    "dynenv_ros/scenarios/soccer.py": "test_scenarios_registry.py",
    "dynenv_ros/security/keys.py": "test_weights_signing.py",
    "dynenv_ros/security/weights_download.py": "test_weights_signing.py",
    "dynenv_ros/security/weights_order.py": "test_weights_signing.py",
    "dynenv_ros/security/weights_source.py": "test_weights_signing.py",
    "dynenv_ros/sim/frames.py": "test_tf.py",
    "dynenv_ros/sim/ground_truth.py": "test_soccer_ground_truth.py",
    "dynenv_ros/sim/physics.py": "test_soccer_robot_motions.py",
    "dynenv_ros/sim/reward_terms.py": "test_soccer_rewards.py",
    "dynenv_ros/sim/scenario.py": "test_driving_world.py",
    "dynenv_ros/sim/seeding.py": "test_sim_node_faults.py",
    "dynenv_ros/soccer/actions.py": "test_robocup_v0.py",
    "dynenv_ros/soccer/agent_actions.py": "test_scenarios_registry.py",
    "dynenv_ros/soccer/config.py": "test_soccer_world_rules.py",
    "dynenv_ros/soccer/observation_columns.py": "test_padded_layout.py",
    "dynenv_ros/soccer/placement.py": "test_soccer_world_rules.py",
    "dynenv_ros/soccer/referee.py": "test_soccer_world_rules.py",
    "policy_node/batch_policy.py": "test_decider.py",
    "policy_node/node_diagnostics.py": "test_policy_node_faults.py",
    "policy_node/node_inputs.py": "test_policy_node_faults.py",
    "policy_node/node_parameters.py": "test_policy_node_faults.py",
    "policy_node/operator_services.py": "test_operator_attacks.py",
    "policy_node/periods.py": "test_partial_periods.py",
    "policy_node/policy_files.py": "test_decider.py",
    "policy_node/scripted_driver.py": "test_sim_node_driving.py",
    "policy_node/scripted_policy.py": "test_action_auth_graph.py",
    "policy_node/weights_following.py": "test_policy_weights.py",
}
WITHOUT_TEST = {
    "dynenv_ros/learning/algo/compiled.py": "torch_compile: true is run by no test (a 15-60 s compile); only restore(), "
                                            "a no-op without it, runs at the end of every training run",
    "dynenv_ros/learning/pretrain/__main__.py": "the `python -m` entry; tests call the package's main() directly",
}
# A dotted module name in a string: what ``python -m``, a node list or a probe process names.
DOTTED = re.compile(r"\b(?:%s)(?:\.\w+)+" % "|".join(PACKAGES))


def modules() -> list[str]:
    """Every module the rule is about, as a path from the repository root."""
    return sorted(path.relative_to(REPO).as_posix() for package in PACKAGES
                  for path in (REPO / package).rglob("*.py") if path.name != "__init__.py")


def named_after(module: str, test_files: list[str]) -> list[str]:
    """The test files whose name says they test ``module`` (the names of the rule in the docstring)."""
    path = Path(module)
    name, folder = path.stem, path.parent.name
    return [file for file in test_files
            if file == f"test_{name}.py" or file.startswith((f"test_{name}_", f"test_{folder}_{name}"))]


def _docstrings(tree: ast.AST) -> set[int]:
    return {id(node.body[0].value) for node in ast.walk(tree)
            if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and node.body
            and isinstance(node.body[0], ast.Expr) and isinstance(node.body[0].value, ast.Constant)}


def named_modules(source: str) -> set[str]:
    """What a test's source imports (anywhere in it) and the modules its strings name, docstrings left out."""
    tree = ast.parse(source)
    docstrings = _docstrings(tree)
    names = set(ros_marking.imported_modules(tree, "", module_level_only=False))
    names |= {found for node in ast.walk(tree)
              if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docstrings
              for found in DOTTED.findall(node.value)}
    return names


def reached(source: str) -> set[str]:
    """The repository's modules (and test/'s helpers) a test's source loads: what it names, then what those import,
    inside functions too. Importing ``a.b.c`` loads ``a`` and ``a.b`` as well."""
    seen: set[str] = set()
    pending = list(named_modules(source))
    while pending:
        parts = pending.pop().split(".")
        for depth in range(1, len(parts) + 1):
            module = ".".join(parts[:depth])
            if module not in seen and ros_marking.local_file(module) is not None:
                seen.add(module)
                pending.extend(_loads(module))
    return seen


@functools.lru_cache(maxsize=None)
def _loads(module: str) -> tuple[str, ...]:
    """What a local module imports, anywhere in it; a helper of test/ also what its strings name (it may start a
    module as a process)."""
    path = ros_marking.local_file(module)
    assert path is not None, module
    if path.parent == TEST_DIR:
        return tuple(named_modules(path.read_text()))
    package = module if path.name == "__init__.py" else ros_marking.package_of(path)
    tree = ast.parse(path.read_text(), filename=str(path))
    return tuple(ros_marking.imported_modules(tree, package, module_level_only=False))


def _dotted(module: str) -> str:
    return module.removesuffix(".py").replace("/", ".")


@functools.lru_cache(maxsize=None)
def reached_by(test_file: str) -> frozenset[str]:
    """``reached`` for a file of test/, once per run."""
    return frozenset(reached((TEST_DIR / test_file).read_text()))


def found_by_name(module: str, test_files: list[str]) -> list[str]:
    """The test files named after ``module`` that reach it: the rule."""
    return [file for file in named_after(module, test_files) if _dotted(module) in reached_by(file)]


def _test_files() -> list[str]:
    return sorted(path.name for path in TEST_DIR.glob("test_*.py"))


@pytest.mark.parametrize(("module", "test_file", "named"), [
    ("dynenv_ros/agent/export.py", "test_export.py", True),
    ("dynenv_ros/agent/export.py", "test_export_driving.py", True),
    ("dynenv_ros/agent/export.py", "test_agent_export.py", True),
    ("dynenv_ros/agent/export.py", "test_agent_export_driving.py", True),
    ("dynenv_ros/agent/export.py", "test_exporter.py", False),            # another name that starts alike
    ("dynenv_ros/agent/export.py", "test_policy_export.py", False),       # the module's name, not at the start
    ("dynenv_ros/learning/algo/advantages.py", "test_learning_advantages.py", False),   # not the nearest folder
    ("dynenv_ros/learning/algo/advantages.py", "test_algo_advantages.py", True),
    ("policy_node/periods.py", "test_policy_node_periods.py", True),
    ("policy_node/periods.py", "test_partial_periods.py", False),
])
def test_the_names_of_the_rule(module: str, test_file: str, named: bool) -> None:
    assert bool(named_after(module, [test_file])) is named


def test_a_name_counts_only_with_the_module_reached() -> None:
    """test_soccer_field.py's name fits evaluation/soccer.py, but it loads nothing of the evaluation."""
    module = "dynenv_ros/evaluation/soccer.py"
    assert named_after(module, ["test_soccer_field.py", "test_evaluation_soccer.py"]) == [
        "test_soccer_field.py", "test_evaluation_soccer.py"]
    assert found_by_name(module, ["test_soccer_field.py", "test_evaluation_soccer.py"]) == ["test_evaluation_soccer.py"]


def test_what_a_test_reaches() -> None:
    """Through the repository's imports, inside functions too; a module named for ``python -m``; not a docstring."""
    imports_a_node = "def test_node():\n    from dynenv_ros.nodes.sim_node import SimNode\n"
    assert "dynenv_ros.ros.sim_parameters" in reached(imports_a_node)      # sim_node imports it
    assert "dynenv_ros.nodes" in reached(imports_a_node)                   # the package on the way
    starts_a_process = "CMD = [sys.executable, '-m', 'dynenv_ros.envs.play', '--help']\n"
    assert "dynenv_ros.envs.play" in reached(starts_a_process)
    assert reached('"""Tests of dynenv_ros.envs.play."""\n') == set()
    assert "dynenv_ros.soccer.world" in reached("from soccer_helpers import make_world\n")   # a helper of test/


def test_every_module_has_a_test_found_by_its_name_or_listed() -> None:
    """A new module gets a test named after it (the rule above), or an entry in COVERED_BY naming the test file
    that exercises it."""
    files = _test_files()
    missing = [module for module in modules()
               if not found_by_name(module, files) and module not in COVERED_BY and module not in WITHOUT_TEST]
    assert missing == [], ("no test file named after these modules reaches them (test/test_suite_names.py's docstring "
                           f"has the rule; else list the test that exercises each in COVERED_BY): {missing}")


def test_each_listed_test_file_exists_and_reaches_its_module() -> None:
    every_module = set(modules())
    for module, test_file in sorted(COVERED_BY.items()):
        assert module in every_module, f"COVERED_BY lists {module}, which is not a module of {PACKAGES}"
        assert (TEST_DIR / test_file).is_file(), f"COVERED_BY: {module}'s test {test_file} is not in test/"
        assert _dotted(module) in reached_by(test_file), f"COVERED_BY: {test_file} does not reach {module}"


def test_the_lists_hold_only_modules_that_need_them() -> None:
    """A module that got a test named after it leaves the lists; a listed one exists; no module is in both."""
    files, every_module = _test_files(), set(modules())
    for module in [*COVERED_BY, *WITHOUT_TEST]:
        assert module in every_module, f"{module} is listed but is not a module of {PACKAGES}"
        assert found_by_name(module, files) == [], (f"{module} is found by its name now "
                                                    f"({found_by_name(module, files)}): remove its entry")
    assert set(COVERED_BY) & set(WITHOUT_TEST) == set()
