"""The agent network (torch, ROS-free): input adapter, RTA encoder, actor-critic, curiosity and self-supervised heads."""
