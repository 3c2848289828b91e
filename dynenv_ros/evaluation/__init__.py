"""ROS-free evaluation of trained policies (``dynenv-eval``): soccer teams against an opponent (``soccer``), drivers
driving every car (``driving``), both over episodes x seeds with seeds as the unit; the result files and their
statistics (``results``), what both play with (``episodes``), BEST comparisons (``best``) and the command (``cli``).
It may use ``dynenv_ros.learning`` to load a training checkpoint; the learning code never imports it."""
