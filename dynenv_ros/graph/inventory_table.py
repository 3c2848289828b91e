"""The committed classes of the ROS inventory (``graph/inventory.py``, docs/ros_graph.md "Inventory"): for each
node, each service, published and subscribed topic and parameter its default start (with the security options on,
so every entry shows) offers, its class and how it is protected. A new entry needs a line here, or
test/test_inventory.py fails."""
from __future__ import annotations

KINDS = ("services", "publishes", "subscribes", "parameters")
ACTS, GAME, READ = "acts", "game", "read"
LABELS = {ACTS: "changes what a robot does or learns", GAME: "changes the game", READ: "read-only"}
NODES = ("sim_node", "sim_node ros_sports", "policy_node", "policy_node ros_sports", "trainer_node", "scripted_policy",
         "perceiving_policy", "scripted_driver", "vision_adapter", "motion_emulator", "recorder")

# Protections, as the table says them.
START = "set at start only (read-only, or read once)"
RUNTIME = "off with `runtime_controls:=false` (deployment profile, train graph); else none"
OPERATOR = "signed operator request (Ed25519); off without `trusted_operator_keys` (deployment profile)"
ACTION_MAC = "MAC under the team's secret with `secrets_dir` (deployment profiles, train graph); else none"
FEEDBACK_MAC = "MAC under `simulator.secret` with `secrets_dir`; else none"
FRAME_TAG = "tag under `frames.secret` with `authenticated_frames` (train graph); none on a robot"
NONE = "none (DDS without SROS2)"
WEIGHTS = "signed release (Ed25519, trusted key, order)"
FETCH = ("named in the signed announcement, with the key id; answers checked against the signed digests; a racing "
         "answer delays this route only (the blob topic delivers)")
BLOB = ("every sample checked against the signed digests (content-addressed); other writers' samples refused, "
        "counted, never displace the trainer's")
MOTION = ("none: a walk engine's commands are not authenticated, on a robot either (keep the domain to the robot, "
          "or SROS2)")
GC = "none: game_controller_spl relays the GameController's unauthenticated UDP as it comes"


def _standard(set_class: str, set_protection: str) -> dict[str, tuple[str, str]]:
    """rclpy's parameter services and rosout/parameter_events of every node."""
    reads = {f"~/{s}": (READ, NONE) for s in ("describe_parameters", "get_parameter_types", "get_parameters",
                                              "get_type_description", "list_parameters")}
    return {**reads, "~/set_parameters": (set_class, set_protection),
            "~/set_parameters_atomically": (set_class, set_protection)}


_COMMON_TOPICS = {"/rosout": (READ, NONE), "/parameter_events": (READ, NONE)}


def _params(klass: str, names: str, protection: str = START) -> dict[str, tuple[str, str]]:
    return {name: (klass, protection) for name in names.split()}


_RUNTIME_FLAGS = _params(READ, "use_sim_time start_type_description_service")
CLASSES: dict[str, dict[str, dict[str, tuple[str, str]]]] = {
    "sim_node": {
        "services": {"/sim/reset": (GAME, RUNTIME), "/sim/step": (GAME, RUNTIME), **_standard(GAME, RUNTIME)},
        "publishes": {**_COMMON_TOPICS, "/<robot>/detections": (ACTS, FRAME_TAG),
                      "/<robot>/detections_mac": (READ, "the tag itself (HMAC)"),
                      "/<robot>/feedback": (ACTS, FEEDBACK_MAC), "/<robot>/pose_estimate": (ACTS, NONE),
                      "/clock": (GAME, NONE), "/world_state": (ACTS, FRAME_TAG),
                      "/world_state_mac": (READ, "the tag itself (HMAC)"), "/tf": (READ, NONE),
                      "/tf_static": (READ, NONE), "/diagnostics": (READ, NONE), "/sim/diagnostics": (READ, NONE),
                      "/sim/markers/detections": (READ, NONE), "/sim/markers/ground_truth": (READ, NONE)},
        "subscribes": {"/<robot>/action": (ACTS, ACTION_MAC), "/recorder/diagnostics": (READ, NONE)},
        "parameters": {**_params(GAME, "scenario players_per_team n_cars action_mode teams mode perception_preset "
                                       "noise_mode noise_magnitude physics_hz vision_period_ticks "
                                       "motion_period_ticks episode_seconds falls_enabled seed localization "
                                       "controlled_robots secrets_dir authenticated_frames runtime_controls "
                                       "ros_sports gc_team_number_a gc_team_number_b gc_udp_port gc_udp_host "
                                       "gc_return_port gc_struct_version"),
                       **_params(GAME, "real_time_factor missing_action auto_reset", RUNTIME),
                       **_params(READ, "publish_markers marker_robot", RUNTIME),
                       **_params(READ, "diagnostics_period wait_for_subscribers wait_for_ground_truth_subscribers "
                                       "wait_for_recorder exit_when_finished report_path foxglove_port "
                                       "foxglove_host"), **_RUNTIME_FLAGS}},
    "policy_node": {
        "services": {"~/load_policy": (ACTS, OPERATOR), "~/accept_older_weights": (ACTS, OPERATOR),
                     **_standard(ACTS, RUNTIME + "; `use_sim_time` moves the decision deadline's clock")},
        "publishes": {**_COMMON_TOPICS, "/<robot>/action": (ACTS, ACTION_MAC), "/diagnostics": (READ, NONE),
                      "~/diagnostics": (READ, NONE)},
        "subscribes": {"/<robot>/detections": (ACTS, FRAME_TAG),
                       "/<robot>/detections_mac": (READ, "the tag itself (HMAC)"),
                       "/trainer/weights_announcement": (ACTS, WEIGHTS), "/trainer/weights_blob": (ACTS, BLOB)},
        "parameters": {**_params(ACTS, "scenario players_per_team n_cars cars team action_mode checkpoint runtime "
                                       "greedy seed decision_deadline pose_frame pose_max_age weights_topic "
                                       "weights_run_id trusted_weights_keys max_weights_bytes "
                                       "weights_state_file trusted_operator_keys allow_unsigned_files secrets_dir "
                                       "authenticated_frames runtime_controls interfaces vision_hz frames_per_period "
                                       "frame_epoch frame_tolerance frame_phase_gain class_wait frame_classes "
                                       "detection_frame perception_preset head_yaw_joint head_yaw_max_age "
                                       "state_max_age gc_team_number_a gc_team_number_b gc_player_number "
                                       "episode_id"),
                       **_params(READ, "diagnostics_period"), **_RUNTIME_FLAGS}},
    "trainer_node": {
        "services": {"/trainer/fetch_weights_<key_id>": (READ, FETCH), **_standard(ACTS, RUNTIME)},
        "publishes": {**_COMMON_TOPICS, "/trainer/weights_announcement": (ACTS, WEIGHTS),
                      "/trainer/weights_blob": (ACTS, BLOB),
                      "/trainer/diagnostics": (READ, NONE), "/diagnostics": (READ, NONE)},
        # experience topics are subscribed as games appear: the sim_node's /<robot>/detections (and _mac),
        # /<robot>/action, /<robot>/feedback, /world_state (and _mac), with their protections above
        "subscribes": {},
        "parameters": {**_params(ACTS, "scenario players_per_team n_cars action_mode variant sequence_length "
                                       "feature_size gamma normalize_advantages reward_weights max_minutes "
                                       "max_updates batch_sequences max_batch_sequences ppo_epochs "
                                       "ppo_minibatches run_dir initial_policy resume learning_team patience seed "
                                       "torch_threads secrets_dir authenticated_frames signing_key "
                                       "runtime_controls"),
                       **_params(ACTS, "learning_rate entropy_coef max_policy_lag publish_every_updates", RUNTIME),
                       **_params(READ, "checkpoint_every_minutes keep_checkpoints diagnostics_period"),
                       **_RUNTIME_FLAGS}},
    "scripted_policy": {
        "services": _standard(READ, START),
        "publishes": {**_COMMON_TOPICS, "/<robot>/action": (ACTS, ACTION_MAC), "/diagnostics": (READ, NONE)},
        "subscribes": {"/<robot>/detections": (ACTS, NONE), "/world_state": (ACTS, NONE)},
        "parameters": {**_params(ACTS, "robot policy seed secrets_dir"), **_RUNTIME_FLAGS}},
    "perceiving_policy": {
        "services": _standard(READ, START),
        "publishes": {**_COMMON_TOPICS, "/<robot>/action": (ACTS, ACTION_MAC), "/diagnostics": (READ, NONE)},
        "subscribes": {"/<robot>/detections": (ACTS, NONE), "/<robot>/pose_estimate": (ACTS, NONE)},
        "parameters": {**_params(ACTS, "robot players_per_team period_seconds pose_frame pose_max_age "
                                       "secrets_dir"), **_RUNTIME_FLAGS}},
    "scripted_driver": {
        "services": _standard(READ, START),
        "publishes": {**_COMMON_TOPICS, "/<robot>/action": (ACTS, ACTION_MAC), "/diagnostics": (READ, NONE)},
        "subscribes": {"/<robot>/detections": (ACTS, NONE), "/world_state": (ACTS, NONE)},
        "parameters": {**_params(ACTS, "n_cars cars action_mode cruise_speed secrets_dir"), **_RUNTIME_FLAGS}},
    "vision_adapter": {
        "services": _standard(READ, START),
        "publishes": {**_COMMON_TOPICS, "/<robot>/detections_3d": (READ, NONE), "/diagnostics": (READ, NONE),
                      "~/diagnostics": (READ, NONE)},
        "subscribes": {"/<robot>/detections": (READ, NONE)},
        "parameters": {**_params(ACTS, "robots players_per_team perception_preset vision_hz frames_per_period "
                                       "episode_id frame_epoch frame_phase_gain frame_tolerance head_yaw_joint "
                                       "head_yaw_max_age state_max_age reverse"),
                       **_params(READ, "diagnostics_period"), **_RUNTIME_FLAGS}},
    "recorder": {
        "services": _standard(READ, START),
        "publishes": {**_COMMON_TOPICS, "/diagnostics": (READ, NONE), "~/diagnostics": (READ, NONE)},
        "subscribes": {},
        "parameters": {**_params(READ, "output topics duration"), **_RUNTIME_FLAGS}},
}

# The nodes' ros-sports options (issue 41), started on: what they add to the entries above.
_ROS_SPORTS_SIM = {f"/<robot>/soccer_vision_3d/{k}": (ACTS, NONE) for k in ("balls", "robots", "goalposts", "markings")}
_ROS_SPORTS_SIM.update({"/<robot>/gc/data": (ACTS, GC), "/<robot>/joint_states": (ACTS, NONE),
                        "/<robot>/fallen": (ACTS, NONE)})
CLASSES["sim_node ros_sports"] = {**CLASSES["sim_node"],
                                  "publishes": {**CLASSES["sim_node"]["publishes"], **_ROS_SPORTS_SIM}}
_ROS_SPORTS_IN = {f"/<robot>/soccer_vision_3d/{k}": (ACTS, NONE) for k in ("balls", "robots", "goalposts", "markings")}
_ROS_SPORTS_IN.update({"/<robot>/soccer_vision_3d/field_boundary": (READ, "none (read and ignored)"),
                       "/<robot>/soccer_vision_3d/obstacles": (READ, "none (read and ignored)"),
                       "/<robot>/gc/data": (ACTS, GC), "/<robot>/joint_states": (ACTS, NONE),
                       "/<robot>/fallen": (ACTS, NONE), "/<robot>/pose_estimate": (ACTS, NONE),
                       "/trainer/weights_announcement": (ACTS, WEIGHTS), "/trainer/weights_blob": (ACTS, BLOB)})
_POLICY = CLASSES["policy_node"]
CLASSES["policy_node ros_sports"] = {
    "services": _POLICY["services"],
    "publishes": {**_POLICY["publishes"], "/<robot>/cmd_vel": (ACTS, MOTION), "/<robot>/motion/kick": (ACTS, MOTION),
                  "/<robot>/motion/head": (ACTS, MOTION)},
    "subscribes": _ROS_SPORTS_IN,
    "parameters": _POLICY["parameters"]}
CLASSES["motion_emulator"] = {
    "services": _standard(READ, START),
    "publishes": {**_COMMON_TOPICS, "/<robot>/action": (ACTS, ACTION_MAC), "/diagnostics": (READ, NONE)},
    "subscribes": {"/<robot>/cmd_vel": (ACTS, MOTION), "/<robot>/motion/kick": (ACTS, MOTION),
                   "/<robot>/motion/head": (ACTS, MOTION), "/<robot>/feedback": (READ, FEEDBACK_MAC)},
    "parameters": {**_params(ACTS, "players_per_team team robots motion_period command_timeout stamp_tolerance "
                                   "twist_max_age head_yaw_joint secrets_dir"), **_RUNTIME_FLAGS}}
