"""A live view of the simulator without a ROS desktop: Foxglove's WebSocket server (``foxglove-sdk``) streams the
field, the robots (cars), each agent's detections, the TF tree and the score to the Foxglove app in a browser.

``scene``: the simulator's state (``WorldSnapshot``, DETECTION_DTYPE rows, ``sim.frames`` transforms) as Foxglove's
well-known messages. ``server``: the WebSocket server and its channels (``LiveView``). Neither imports ROS: the
simulator node and the main job only switch it on (``foxglove_port``; docs/ros_graph.md, "Live view in Foxglove").
"""
