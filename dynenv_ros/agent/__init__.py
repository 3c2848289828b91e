"""The DynEnv agent (torch, ROS-free): input adapter, RTA encoder, actor-critic, curiosity and self-supervised
heads, checkpoints and ONNX export. ``policy_node`` (ROS) and ``dynenv_ros.learning`` (training) both use it."""
