"""ROS-free learning: rollouts, algorithms, losses wiring, checkpoints (evaluation: ``dynenv_ros.evaluation``)."""
