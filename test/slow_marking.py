"""Which tests are ``slow``: the measured list behind the marker (test/conftest.py applies it; docs/setup.md#tests).

A test is slow when it took at least ``THRESHOLD_S`` seconds (setup, call and teardown together) in the measuring
run: the whole suite with ``pytest -n 2 --durations=0 -p no:cacheprovider test`` on the 2-core development machine
while it was shared (load average 6 to 26), where the suite took 6,094 s against 920 s in CI: 15 s there is about
2.3 s on an idle machine. Only the ranking of that run is trusted, not its seconds; ``MEASURED`` keeps its figure
for each entry so that the next measurement can be compared.

An entry is ``file::function`` (every parametrization) or ``file::function[id]`` (that one, where the others were
quick). A new test that takes long joins the list by hand, or by measuring again: ``python test/slow_marking.py
LOG`` prints the entries of a ``--durations=0`` log. test_ros_marking.py fails for an entry that names no test.
"""
from __future__ import annotations

import re
import sys
from collections import defaultdict
from pathlib import Path

THRESHOLD_S = 15.0
MEASURED: dict[str, float] = {
    "test_action_auth_graph.py::test_every_policy_node_tags_what_it_sends[driving]": 28,
    "test_action_auth_graph.py::test_the_simulator_runs_only_the_genuine_teams_actions": 21,
    "test_async_trainer.py::test_a_killed_worker_is_counted_and_replaced_then_the_run_stops_cleanly_when_none_is_left": 22,
    "test_async_trainer.py::test_a_resumed_async_runs_summary_counts_the_whole_run": 28,
    "test_async_trainer.py::test_a_worker_process_delivers_what_the_same_worker_makes_in_process": 20,
    "test_async_trainer.py::test_an_async_run_learns_within_its_lag_bound_and_writes_a_whole_run_directory": 31,
    "test_async_trainer.py::test_every_kind_of_run_trains_asynchronously": 45,
    "test_async_trainer.py::test_the_learner_killed_takes_its_workers_and_resumes_from_its_checkpoint": 62,
    "test_async_trainer.py::test_the_tiny_task_is_learnt_asynchronously_as_in_process_at_equal_env_steps": 76,
    "test_best.py::test_identical_groups_compared_by_the_cli_give_no_difference": 19,
    "test_best.py::test_large_separation_is_found": 16,
    "test_best_policy.py::test_a_run_keeps_the_policy_where_training_best_finds_the_peak_and_a_resume_goes_on": 40,
    "test_camera_timing.py::test_a_jittery_dropping_late_camera_gets_an_action_in_most_periods": 36,
    "test_camera_timing.py::test_without_a_deadline_a_dropping_camera_leaves_periods_unanswered": 20,
    "test_colcon_build.py::test_colcon_builds_both_packages_into_a_ros_layout": 258,
    "test_doc_commands.py::test_doc_commands_work_as_written[README.md]": 62,
    "test_doc_commands.py::test_doc_commands_work_as_written[docs/benchmarks.md]": 460,
    "test_doc_commands.py::test_doc_commands_work_as_written[docs/deploy.md]": 60,
    "test_doc_commands.py::test_doc_commands_work_as_written[docs/driving.md]": 62,
    "test_doc_commands.py::test_doc_commands_work_as_written[docs/perception.md]": 41,
    "test_doc_commands.py::test_doc_commands_work_as_written[docs/results.md]": 1179,
    "test_doc_commands.py::test_doc_commands_work_as_written[docs/ros_graph.md]": 205,
    "test_doc_commands.py::test_doc_commands_work_as_written[docs/tour.md]": 260,
    "test_doc_commands.py::test_doc_commands_work_as_written[docs/training.md]": 395,
    "test_doc_commands.py::test_the_docs_venv_service_calls_reach_the_node": 23,
    "test_driving_perception_leaks.py::test_no_feature_but_the_confidence_adds_to_what_the_geometry_says": 71,
    "test_driving_scripted.py::test_scripted_cars_reach_their_destinations_among_pedestrians": 20,
    "test_driving_teacher.py::test_following_the_labels_replays_the_scripted_driver_and_backends_agree": 18,
    "test_driving_teacher.py::test_the_labels_are_stored_and_imitation_alone_brings_the_policy_to_the_driver[discrete]": 15,
    "test_driving_world.py::test_sim_benchmark_runs_the_driving_world": 32,
    "test_evaluation_driving.py::test_cli_driving_writes_json_and_compare_runs": 19,
    "test_evaluation_driving.py::test_merge_makes_each_run_one_unit_and_refuses_what_does_not_fit": 26,
    "test_frame_auth_graph.py::test_no_forged_frame_reaches_the_policys_decisions_or_the_trainers_experience": 202,
    "test_inference_server.py::test_a_dead_worker_is_replaced_and_served_and_a_dead_server_stops_the_run_in_one_line": 17,
    "test_inference_server.py::test_a_run_with_the_server_trains_checkpoints_and_resumes": 18,
    "test_inference_server.py::test_every_kind_of_run_trains_with_the_server": 10,
    "test_inference_server.py::test_worker_processes_served_by_the_server_make_the_rollouts_they_make_acting_themselves": 18,
    "test_layout.py::test_the_trainer_and_the_ros_graph_import_without_ray": 50,
    "test_league.py::test_a_resumed_league_run_carries_on_each_workers_league[async]": 17,
    "test_league.py::test_a_run_against_the_league_trains_and_logs_the_members": 88,
    "test_league.py::test_a_run_over_two_team_sizes_trains": 93,
    "test_learning_driving.py::test_ppo_learns_to_drive_towards_the_destination_within_seconds": 127,
    "test_learning_driving.py::test_trainer_writes_a_driving_run": 24,
    "test_learning_learns.py::test_ppo_learns_to_walk_to_the_ball_within_seconds": 37,
    "test_learning_teacher.py::test_imitation_alone_makes_the_policy_agree_with_the_teacher": 31,
    "test_learning_update.py::test_ltp_is_optimised_through_the_training_update": 18,
    "test_live_view_server.py::test_the_sim_node_refuses_a_bad_or_taken_port": 17,
    "test_localization.py::test_penalty_and_reentry_reset_to_the_touchline_prior": 22,
    "test_localization.py::test_steady_state_error_while_landmarks_are_seen_is_a_few_centimetres[0.0-4]": 20,
    "test_main_job.py::test_main_job_plays_a_trained_policy_for_team_a": 70,
    "test_main_job.py::test_main_job_plays_records_and_replays_a_driving_game": 58,
    "test_main_job.py::test_main_job_plays_records_and_replays_a_soccer_game": 75,
    "test_main_job.py::test_main_job_plays_the_perceiving_team_on_detections_and_pose_estimates": 41,
    "test_main_job.py::test_malformed_config_file_is_refused": 19,
    "test_main_job.py::test_the_train_graph_runs_games_policies_and_the_trainer_and_summarises": 1312,
    "test_main_job.py::test_the_train_graph_verdict_plays_the_start_and_end_policies_on_held_out_episodes": 69,
    "test_message_trainer.py::test_dynenv_train_resumes_a_run_directory_the_trainer_node_wrote": 40,
    "test_message_trainer.py::test_the_learner_resumes_a_run_directory_dynenv_train_wrote": 36,
    "test_messages_bags.py::test_cloning_the_recorded_team_lowers_its_losses_and_writes_a_policy": 17,
    "test_messages_bags.py::test_the_cli_learns_from_a_bag_and_refuses_what_is_not_one": 21,
    "test_messages_bags_driving.py::test_a_driving_bag_is_cloned_into_a_driving_policy": 25,
    "test_network_split.py::test_experience_and_weights_cross_a_network_boundary": 149,
    "test_operator_attacks.py::test_accept_older_weights_obeys_only_the_operator_and_no_rollback_acts": 18,
    "test_package_dependencies.py::test_every_import_of_the_package_is_in_the_table": 19,
    "test_package_dependencies.py::test_test_dependencies_are_declared": 18,
    "test_paper_comparison.py::test_paper_comparison_on_fixture_runs": 60,
    "test_perceiving_teacher.py::test_a_tiny_run_with_the_perceiving_teacher_trains_and_checkpoints": 68,
    "test_perceiving_teacher.py::test_the_labels_agree_across_backends_and_do_not_depend_on_observing_the_estimate": 27,
    "test_perception_driving_model.py::test_lanes_are_clipped_to_the_range_with_an_observer_frame_endpoint_order": 20,
    "test_perception_leaks.py::test_no_feature_but_the_confidence_adds_to_what_the_geometry_says": 547,
    "test_policy_node_faults.py::test_load_policy_refuses_what_would_crash_or_stall_and_keeps_playing[head_units_0-torch]": 16,
    "test_pose_observation.py::test_a_tiny_run_with_the_estimate_trains_checkpoints_resumes_and_evaluates": 54,
    "test_ray_cluster.py::test_a_grid_of_runs_runs_as_tasks_on_the_cluster": 60,
    "test_ray_cluster.py::test_an_address_nobody_answers_at_is_refused_within_its_timeout": 19,
    "test_ray_cluster.py::test_an_embedded_local_ray_trains_with_its_actors": 108,
    "test_ray_cluster.py::test_more_workers_than_the_cluster_has_are_refused_in_one_line": 55,
    "test_ray_cluster.py::test_training_uses_both_nodes_and_goes_on_when_the_second_dies": 103,
    "test_rl_libraries.py::test_stable_baselines3_ppo_learns_from_the_supersuit_batch": 82,
    "test_robocup_v0.py::test_same_seed_and_actions_give_the_same_episode_and_another_seed_does_not": 16,
    "test_run_compute.py::test_a_run_records_its_compute_and_a_resumed_run_keeps_both_segments": 56,
    "test_run_compute.py::test_cpu_seconds_count_a_live_child_process": 75,
    "test_run_compute.py::test_init_policy_starts_every_network_from_the_file": 31,
    "test_runtime_controls.py::test_with_the_local_default_the_same_calls_change_the_game": 17,
    "test_sample_bag.py::test_a_bag_recorded_before_detection_arrays_carried_the_game_controller_still_reads": 19,
    "test_sim_node_driving.py::test_scripted_drivers_drive_every_car_without_a_refusal[discrete]": 15,
    "test_sim_node_faults.py::test_a_mistyped_parameter_is_refused_naming_the_known_ones": 49,
    "test_sim_node_faults.py::test_a_sigint_while_the_realtime_simulator_starts_stops_it_cleanly[inbox_thread_started]": 16,
    "test_sim_node_faults.py::test_every_node_run_through_the_node_runner_answers_help[policy_node.policy_node]": 32,
    "test_sim_node_faults.py::test_ill_typed_reset_options_and_seeds_are_refused_and_the_node_lives_on": 34,
    "test_sim_node_faults.py::test_sim_node_help_lists_its_parameters_and_exits_without_starting_ros": 19,
    "test_soccer_ground_truth.py::test_play_tool_draws_one_robots_detections": 23,
    "test_soccer_ground_truth.py::test_sim_benchmark_defaults_to_the_step_training_runs_and_says_so": 59,
    "test_sweep_evaluation.py::test_greedy_reaches_the_policys_evaluation_and_not_a_reference_driver": 28,
    "test_sweep_scratch.py::test_a_scratch_folder_without_a_checkpoint_starts_over": 62,
    "test_sweep_scratch.py::test_a_scratch_run_with_a_checkpoint_is_resumed_not_restarted": 353,
    "test_train_cli.py::test_resume_with_every_checkpoint_damaged_is_refused_and_loses_nothing": 42,
    "test_train_cli.py::test_sigkill_then_resume_from_the_last_checkpoint": 151,
    "test_train_disk.py::test_resume_into_a_full_run_dir_is_refused_in_one_line": 47,
    "test_train_disk.py::test_resume_of_a_run_killed_before_its_first_checkpoint_starts_it_again": 69,
    "test_train_disk.py::test_sigkill_right_after_the_first_checkpoint_then_resume_continues": 41,
    "test_train_disk.py::test_the_disk_estimate_covers_what_a_run_writes": 39,
    "test_trainer_faults.py::test_a_killed_simulator_leaves_the_trainer_learning_from_the_other_games": 45,
    "test_trainer_faults.py::test_a_killed_trainer_leaves_the_robots_playing_and_a_restarted_one_resumes": 130,
    "test_trainer_node.py::test_several_games_in_their_namespaces_feed_one_trainer": 17,
    "test_trainer_node.py::test_the_trainer_rebuilds_what_the_policy_saw_and_chose": 20,
    "test_trainer_node.py::test_weights_flow_back_and_the_policy_acts_with_new_versions": 16,
    "test_trainer_poison.py::test_forged_actions_and_rewards_from_another_process_cannot_kill_learning": 29,
    "test_vector_env.py::test_backends_agree_with_few_slots_and_dropped_rows": 21,
    "test_vector_env.py::test_backends_give_bit_identical_padded_batches_across_episode_ends": 45,
    "test_vector_env.py::test_bad_actions_are_refused_before_any_world_moves[subprocess]": 20,
    "test_vector_env.py::test_copy_false_hands_out_the_batchs_own_arrays": 27,
    "test_vector_env.py::test_errors_in_any_shard_reach_the_caller_and_the_batch_goes_on": 25,
    "test_vector_env.py::test_every_arrangement_of_shards_gives_the_in_process_batches": 30,
    "test_vector_env.py::test_pinned_workers_run_on_one_cpu_each[False]": 17,
    "test_vector_env.py::test_scripted_team_b_plays_in_the_worlds_and_ignores_given_rows": 28,
    "test_vector_env.py::test_shared_memory_is_released_on_close_collection_and_errors": 71,
    "test_vector_env.py::test_world_e_equals_the_pettingzoo_env_with_its_child_seed[subprocess]": 18,
    "test_weights_attacks.py::test_a_release_raced_by_junk_answers_is_taken_once_the_attacker_stops": 24,
}


def key_of(nodeid: str) -> tuple[str, str]:
    """("file::function", "file::function[id]") of a node id such as ``test/test_x.py::test_y[a-b]``."""
    path, _, name = nodeid.partition("::")
    exact = f"{Path(path).name}::{name}"
    return exact.split("[", 1)[0], exact


def is_slow(nodeid: str) -> bool:
    function, exact = key_of(nodeid)
    return function in MEASURED or exact in MEASURED


def entries_from_log(log: str, threshold_s: float = THRESHOLD_S) -> dict[str, float]:
    """The entries a ``--durations=0`` log gives: per test, setup + call + teardown; a function whose every
    measured parametrization is slow is one entry."""
    seconds: dict[str, float] = defaultdict(float)
    for line in log.splitlines():
        found = re.match(r"^\s*([0-9.]+)s (?:call|setup|teardown)\s+(\S+::\S+)", line)
        if found:
            seconds[found.group(2)] += float(found.group(1))
    by_function: dict[str, dict[str, float]] = defaultdict(dict)
    for nodeid, value in seconds.items():
        function, exact = key_of(nodeid)
        by_function[function][exact] = value
    entries: dict[str, float] = {}
    for function, variants in by_function.items():
        slow = {exact: value for exact, value in variants.items() if value >= threshold_s}
        if slow and len(slow) == len(variants):
            entries[function] = max(slow.values())
        else:
            entries.update(slow)
    return dict(sorted(entries.items()))


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: python test/slow_marking.py DURATIONS_LOG (a pytest --durations=0 log of the whole suite)")
    for name, value in entries_from_log(Path(sys.argv[1]).read_text()).items():
        print(f'    "{name}": {value:.0f},')
