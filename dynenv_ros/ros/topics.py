"""Topic and service names of the simulator graph, in one place (docs/ros_graph.md describes each).

The names below are those of a game in the root namespace (what a bag of it shows). Nodes create their endpoints
with ``local(name)``, relative to their namespace, so several games share one ROS graph side by side:
``sim_node --ros-args -r __ns:=/game_1`` publishes ``/game_1/world_state``, ``/game_1/team_a_0/detections`` …, and
a policy node started in the same namespace plays that game only (docs/ros_graph.md, "Several games").
"""
from __future__ import annotations

CLOCK = "/clock"                                  # rosgraph_msgs/Clock, sim time, at vision rate
WORLD_STATE = "/world_state"                      # dynenv_msgs/WorldState, ground truth, frame "map", vision rate
DIAGNOSTICS = "/sim/diagnostics"                  # diagnostic_msgs/DiagnosticArray, about 1 Hz
RECORDER_DIAGNOSTICS = "/recorder/diagnostics"    # diagnostic_msgs/DiagnosticArray, latched; ERROR when not recording
MATCHED_PREFIX = "matched_publishers:"            # + topic: a recorder diagnostics value, publishers it has matched
GROUND_TRUTH_MARKERS = "/sim/markers/ground_truth"  # visualization_msgs/MarkerArray, frame "map"
DETECTION_MARKERS = "/sim/markers/detections"     # visualization_msgs/MarkerArray of one robot's detections
RESET_SERVICE = "/sim/reset"                      # dynenv_msgs/srv/ResetSimulation
STEP_SERVICE = "/sim/step"                        # dynenv_msgs/srv/StepSimulation
# The training graph (docs/ros_graph.md, "Training over ROS"): absolute, one trainer serves every game's policies.
WEIGHTS_ANNOUNCEMENT = "/trainer/weights_announcement"  # dynenv_msgs/WeightsAnnouncement, signed; reliable,
#                                                  transient local, depth 1
FETCH_WEIGHTS = "/trainer/fetch_weights"          # + "_<key id>": dynenv_msgs/srv/FetchWeights, an announced
#                                                  file's chunks by offset (security.weights_source)
WEIGHTS_BLOB = "/trainer/weights_blob"            # dynenv_msgs/srv/FetchWeights_Response: each release's manifest
#                                                  and chunks; reliable, transient local (ros.weights_release)
TRAINER_DIAGNOSTICS = "/trainer/diagnostics"      # diagnostic_msgs/DiagnosticArray, about 1 Hz


def weights_blob(announcement_topic: str) -> str:
    """The blob topic beside an announcement topic: ``/trainer/weights_announcement`` → ``/trainer/weights_blob``."""
    parent, _, _ = announcement_topic.rpartition("/")
    return f"{parent}/weights_blob" if parent or announcement_topic.startswith("/") else "weights_blob"


def local(name: str) -> str:
    """``name`` relative to the node's namespace ('/world_state' → 'world_state'): the same name in the root
    namespace, the game's own in a namespaced one."""
    return name.lstrip("/")


def detections(robot: str) -> str:
    """dynenv_msgs/DetectionArray of one robot, frame "<robot>/camera", vision rate."""
    return f"/{robot}/detections"


def action(robot: str) -> str:
    """dynenv_msgs/Action for one robot, one per motion period (subscribed by the simulator)."""
    return f"/{robot}/action"


def feedback(robot: str) -> str:
    """dynenv_msgs/StepFeedback of one robot, motion rate."""
    return f"/{robot}/feedback"


# A real robot's own topics, read by the reverse vision adapter (nodes/vision_adapter.py, docs/deploy.md): relative,
# in the adapter's namespace.
def detections_3d(robot: str) -> str:
    """vision_msgs/Detection3DArray of one robot: the adapter's output (forward) or a robot's vision stack (reverse)."""
    return f"{robot}/detections_3d"


def joint_states(robot: str) -> str:
    """sensor_msgs/JointState of one robot (the head yaw joint)."""
    return f"{robot}/joint_states"


def fallen(robot: str) -> str:
    """std_msgs/Bool: the robot is down."""
    return f"{robot}/fallen"


def penalized(robot: str) -> str:
    """std_msgs/Bool: the robot is penalized (off the field)."""
    return f"{robot}/penalized"


def game_state(robot: str) -> str:
    """std_msgs/Float32MultiArray: the GameController state as this robot receives it."""
    return f"{robot}/game_state"


SOCCER_VISION_3D_KINDS = ("balls", "robots", "goalposts", "markings", "field_boundary", "obstacles")


def soccer_vision_3d(robot: str, kind: str) -> str:
    """ros-sports soccer_vision_3d_msgs of one robot: ``kind`` balls, robots, goalposts or markings (issue 41;
    the simulator publishes these four), field_boundary or obstacles (a team's stack may; the policy node reads
    and ignores them)."""
    if kind not in SOCCER_VISION_3D_KINDS:
        raise ValueError(f"no soccer_vision_3d topic '{kind}'")
    return f"/{robot}/soccer_vision_3d/{kind}"


# What a policy node with ``interfaces:=ros_sports`` commands (issue 41; docs/deploy.md): the robot's walk engine,
# kick engine and head, in the robot's namespace.
def walk_target(robot: str) -> str:
    """geometry_msgs/Twist: the walk engine's velocity target (base_link: x forward, y left m/s, z rad/s)."""
    return f"/{robot}/cmd_vel"


def kick_request(robot: str) -> str:
    """std_msgs/Bool: one kick request, ``data`` = use_left_foot (the request rUNSWift-derived kick engines take)."""
    return f"/{robot}/motion/kick"


def head_command(robot: str) -> str:
    """sensor_msgs/JointState: the head yaw target (``position``) and rate over the period (``velocity``)."""
    return f"/{robot}/motion/head"


def gc_data(robot: str) -> str:
    """game_controller_spl_interfaces/RCGCD15 as game_controller_spl publishes it, in the robot's namespace."""
    return f"/{robot}/gc/data"


def pose_estimate(robot: str) -> str:
    """geometry_msgs/PoseWithCovarianceStamped: one robot's self-localization estimate, frame "map", vision rate
    (the simulator's with ``localization`` on; a real robot's localization feeds the policy node on the same name)."""
    return f"/{robot}/pose_estimate"


SIM_PUBLISHED_TYPES = {
    "rosgraph_msgs/msg/Clock", "dynenv_msgs/msg/WorldState", "dynenv_msgs/msg/DetectionArray",
    "dynenv_msgs/msg/StepFeedback", "diagnostic_msgs/msg/DiagnosticArray", "visualization_msgs/msg/MarkerArray",
    "tf2_msgs/msg/TFMessage", "geometry_msgs/msg/PoseWithCovarianceStamped",
}
