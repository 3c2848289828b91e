"""ament_python package dynenv_ros: the simulator core, its ROS 2 nodes, the agent (policy_node) and benchmarks."""
from glob import glob
from pathlib import Path

from setuptools import find_packages, setup

PACKAGE = "dynenv_ros"

# Nodes started with `ros2 run dynenv_ros <name>` (colcon installs them under lib/dynenv_ros, see setup.cfg)
# and, in the project venv, as commands of the same name.
NODES = [
    "selfcheck_talker = dynenv_ros.nodes.selfcheck_talker:main",
    "selfcheck_listener = dynenv_ros.nodes.selfcheck_listener:main",
    "sim_node = dynenv_ros.nodes.sim_node:main",
    "scripted_policy = policy_node.scripted_policy:main",
    "perceiving_policy = policy_node.perceiving_policy:main",
    "scripted_driver = policy_node.scripted_driver:main",
    "policy_node = policy_node.policy_node:main",
    "recorder = dynenv_ros.nodes.recorder:main",
    "bag_player = dynenv_ros.nodes.bag_player:main",
    "vision_adapter = dynenv_ros.nodes.vision_adapter:main",
    "trainer_node = dynenv_ros.nodes.trainer_node:main",
    "motion_emulator = dynenv_ros.nodes.motion_emulator:main",
]
# Runtime Python dependencies, for pip (`pip install .`); ROS packages (rclpy, the message packages) come from ROS
# (package.xml, rosdep) and are not on PyPI under these names. Lower bounds only where an older major version lacks
# what the code uses; the exact tested set is requirements.lock, which tools/bootstrap.py installs with --no-deps
# (so these lists never change what `make run` / `make test` install). torch: pip resolves it from the configured
# index (PyPI's Linux default is the CUDA build); install the CPU wheel first for a CPU-only machine (README).
INSTALL_REQUIRES = [
    "numpy>=2", "PyYAML", "scipy", "torch>=2.8", "pymunk>=7", "numba", "rosbags>=0.11", "pettingzoo>=1.24",
    "gymnasium>=1", "pillow", "onnx", "onnxscript", "onnxruntime", "safetensors", "tensorboard", "tqdm",
    "matplotlib", "cryptography", "foxglove-sdk>=0.30",
]
EXTRAS_REQUIRE = {
    # Training on a cluster (backend: ray, dynenv-sweep) and BEST comparisons (dynenv-eval): imported lazily.
    "train": ["ray", "pymc"],
    # The test suite beyond the runtime: RL libraries' route (test_rl_libraries) and the colcon build test.
    "test": ["pytest", "pytest-xdist", "supersuit", "stable-baselines3", "catkin-pkg", "colcon-core", "colcon-ros",
             "colcon-package-selection", "websockets", "protobuf"],
}
TOOLS = [
    "dynenv-run = dynenv_ros.main_job:main",
    "dynenv-bench = benchmarks.__main__:main",
    "dynenv-play = dynenv_ros.envs.play:main",
    "dynenv-bag = dynenv_ros.bags.inspect:main",
    "dynenv-record = dynenv_ros.nodes.recorder:cli_main",
    "dynenv-eval = dynenv_ros.evaluation.cli:main",
    "dynenv-train = dynenv_ros.learning.train_cli:main",
    "dynenv-sweep = dynenv_ros.experiments.sweep:main",
    "dynenv-pretrain = dynenv_ros.learning.pretrain:main",
    "dynenv-keys = dynenv_ros.ros.keys_cli:main",
]

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(include=["dynenv_ros*", "policy_node*", "benchmarks*"]),
    package_data={"dynenv_ros.ros": ["*.xml"]},           # the policy node's Fast DDS profiles (ros/dds_profiles.py)
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", glob("config/*.yaml")),
        (f"share/{PACKAGE}/config/perception", glob("config/perception/*.yaml")),
        (f"share/{PACKAGE}/pretrained", [f for f in glob("policy_node/pretrained/*") if Path(f).is_file()]),
        (f"share/{PACKAGE}/pretrained/eval", glob("policy_node/pretrained/eval/*.json")),
        (f"share/{PACKAGE}/pretrained/driving", [f for f in glob("policy_node/pretrained/driving/*") if Path(f).is_file()]),
        (f"share/{PACKAGE}/pretrained/driving/eval", glob("policy_node/pretrained/driving/eval/*.json")),
        (f"share/{PACKAGE}/config/train", glob("config/train/*.yaml")),
        (f"share/{PACKAGE}/config/foxglove", glob("config/foxglove/*.json")),    # the live view's layout
        (f"share/{PACKAGE}/launch", glob("launch/*.launch.py")),
    ],
    install_requires=INSTALL_REQUIRES,
    extras_require=EXTRAS_REQUIRE,
    zip_safe=True,
    maintainer="dynenv_ros maintainers",
    maintainer_email="maintainers@dynenv-ros.org",
    description="ROS 2 emulation of a robot vision pipeline with realistic perception failures, for multi-agent RL.",
    license="Apache-2.0",
    python_requires=">=3.11",
    entry_points={"console_scripts": NODES + TOOLS},
)
