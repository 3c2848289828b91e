"""tf2_msgs and vision_msgs, rebuilt into the venv from msg_defs/upstream, are the same types as upstream's Jazzy
packages: equal RIHS01 hashes, so DDS peers, bags and tools of a full ROS install interoperate with them."""
import json
import sys
from pathlib import Path

import pytest
from rosbags.typesys import Stores, get_typestore

# Published for upstream vision_msgs 4.x (Humble/Jazzy) by independent generated code (an Elixir ROS 2 client's
# vision_msgs/Detection3DArray module); the hash covers every nested type (Detection3D, ObjectHypothesisWithPose,
# ObjectHypothesis, BoundingBox3D).
UPSTREAM_DETECTION3DARRAY_HASH = "RIHS01_793f5eab9595ac1c0da07873cc859db42eae51f0ee76056db8562515d830e018"


def generated_hash(name: str) -> str:
    package, kind, type_name = name.split("/")
    description = json.loads((Path(sys.prefix) / "share" / package / kind / f"{type_name}.json").read_text())
    return next(e["hash_string"] for e in description["type_hashes"] if e["type_name"] == name)


@pytest.mark.parametrize("name", ["tf2_msgs/msg/TFMessage", "tf2_msgs/msg/TF2Error"])
def test_tf2_msgs_hash_equals_rosbags_jazzy_typestore(name):
    assert generated_hash(name) == get_typestore(Stores.ROS2_JAZZY).hash_rihs01(name)


def test_vision_msgs_detection3darray_hash_equals_upstream():
    assert generated_hash("vision_msgs/msg/Detection3DArray") == UPSTREAM_DETECTION3DARRAY_HASH


def test_rebuilt_packages_import_as_ros_messages():
    from tf2_msgs.msg import TFMessage
    from vision_msgs.msg import Detection3DArray
    assert TFMessage.__module__.startswith("tf2_msgs") and Detection3DArray.__module__.startswith("vision_msgs")


def test_the_bag_typestore_knows_vision_msgs_with_the_upstream_hash():
    """So the recorder can record the vision adapter's /<robot>/detections_3d and the bag tools decode them."""
    from dynenv_ros.bags.typestore import dynenv_typestore
    assert dynenv_typestore().hash_rihs01("vision_msgs/msg/Detection3DArray") == UPSTREAM_DETECTION3DARRAY_HASH
