"""A tiny task that any working learner solves within seconds, so a broken one fails CI: in 1v1 worlds of 5 s from
kick-off, rewarded only by the approach term (closing the distance to the ball), both robots must learn to walk at
the ball. Kick-off puts each robot in its own half facing the centre, where the ball is, so walking forward is the
best action from the start; a learner with a wrong sign or no gradient stays at chance or gets worse."""
import numpy as np
import torch

from dynenv_ros.agent.network import DynEnvAgent
from dynenv_ros.envs.vector import SoccerVectorEnv
from dynenv_ros.learning.algo.ppo import UpdateSettings, update
from dynenv_ros.learning.algo.networks import TrainingNetworks
from dynenv_ros.learning.sampling.collector import RolloutCollector
from dynenv_ros.sim.reward_terms import RewardTerm
from dynenv_ros.soccer.actions import Walk

WALK_CHOICES = 5              # NONE, FORWARD, BACKWARD, LEFT, RIGHT: a uniform policy walks forward 1 time in 5


def test_ppo_learns_to_walk_to_the_ball_within_seconds():
    torch.manual_seed(0)
    env = SoccerVectorEnv(4, backend="inprocess", config={"players_per_team": 1, "episode_seconds": 5.0},
                          perception="none")
    agent = DynEnvAgent(feature_size=32)
    networks = TrainingNetworks(agent, horizon=2)
    generator = torch.Generator().manual_seed(0)
    approach = int(RewardTerm.AUXILIARY)
    collector = RolloutCollector(env, agent, np.arange(2), None, generator, seed=0,
                                 reward_transform=lambda terms: terms[..., approach])
    optimizer = torch.optim.Adam(networks.parameters(), lr=3e-3)
    settings = UpdateSettings(algorithm="ppo", gamma=0.9, gae_lambda=0.9, epochs=4, minibatches=1,
                              normalize_advantages=True, entropy_coef=0.0, use_forward=False, use_rcm=False,
                              use_inverse=False, use_ltp=False)
    try:
        before = collector.collect(10)
        update(networks, optimizer, before.as_tensors(), settings, generator)
        for _ in range(7):
            update(networks, optimizer, collector.collect(10).as_tensors(), settings, generator)
        after = [collector.collect(10) for _ in range(2)]
    finally:
        env.close()
    forward_before = (before.actions[..., 0] == Walk.FORWARD).mean()
    forward_after = np.mean([(r.actions[..., 0] == Walk.FORWARD).mean() for r in after])
    reward_before = before.reward_terms[..., approach].ravel()
    reward_after = np.concatenate([r.reward_terms[..., approach].ravel() for r in after])
    # untrained: about chance (80 samples, binomial SE 0.045 around 0.2); trained: nearly always forward
    assert abs(forward_before - 1 / WALK_CHOICES) < 4 * np.sqrt(0.2 * 0.8 / before.actions[..., 0].size)
    assert forward_after > 0.8
    standard_error = np.sqrt(reward_before.var() / reward_before.size + reward_after.var() / reward_after.size)
    assert reward_after.mean() - reward_before.mean() > 4 * standard_error
