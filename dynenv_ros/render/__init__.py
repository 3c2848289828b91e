"""ROS-free top-down rendering of world snapshots (Pillow only, no display), for rgb_array frames, PNGs and GIFs.

It draws from ``WorldSnapshot`` ground truth alone, so the same code serves the Gymnasium env, offline bag replays
and debugging overlays without knowing a scenario's internals.
"""
