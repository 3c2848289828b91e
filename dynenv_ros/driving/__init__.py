"""The DynEnv driving scenario, ROS-free: map, cars, pedestrians, rules and rewards, scripted driver."""
