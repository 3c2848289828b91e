"""The soccer robot's own columns of the padded observation (``envs.padded_layout``, which re-exports them): what it
knows of itself and what the GameController broadcasts. Defined here, below ``envs``, so that the soccer team that
plays on its own perception (``soccer.perceiving``) reads them without importing the layer above (.importlinter)."""
from __future__ import annotations

PROPRIOCEPTION_COLUMNS = ("head_yaw", "fallen", "penalized", "kicking")
# ball_owner: +1 own team owns the ball (kick-off or set play), -1 the opponents do, 0 free ball; seconds in SI.
GAME_COLUMNS = ("ball_owner", "ball_owner_seconds", "game_seconds_remaining")
