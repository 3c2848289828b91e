"""The algorithm, below every source of experience: what an update learns from (``experience``), the networks a run
trains (``networks``), the policy's forward passes (``policy``), advantages, PPO and A2C with the auxiliary losses, and
the one training loop (``loop``)."""
