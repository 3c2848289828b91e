"""The RoboCup SPL GameController, ROS-free: its UDP packets (``packet``) and the simulated game in its words
(``game_state``)."""
