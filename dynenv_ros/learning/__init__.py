"""ROS-free training, one concern per subpackage (docs/training.md, "The code"): ``algo`` (what an update learns
from, the networks, PPO/A2C, the one training loop), ``sampling`` (this process's worlds), ``distributed`` (rollout
workers: processes, Ray), ``messages`` (the trainer node's experience, recorded bags), ``pretrain`` and ``run`` (a
run's directory); ``config`` (and its ``curriculum`` of start states), ``trainer``, ``resources`` and ``train_cli`` (``dynenv-train``) on top. Evaluation is
``dynenv_ros.evaluation``."""
