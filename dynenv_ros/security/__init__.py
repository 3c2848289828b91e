"""Who may change what a robot does (issue 27): signed weights releases (``weights_signing``, ``keys``) and
authenticated actions (``action_auth``). ROS-free: the nodes call these, this package imports no ROS."""
