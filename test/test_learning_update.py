"""The learner on real rollouts of a small world: each loss reaches the parameters it should (and not those it
must not), PPO's first minibatch has ratio 1 and no clipping, episode ends and truncation are recorded and
bootstrapped from the final observation, and the collector's arrays are the env's layout."""
import numpy as np
import pytest
import torch

from dynenv_ros.agent.network import DynEnvAgent
from dynenv_ros.envs.vector import SoccerVectorEnv
from dynenv_ros.learning.algo.ppo import UpdateSettings, minibatch_loss, update
from dynenv_ros.learning.algo.networks import TrainingNetworks
from dynenv_ros.learning.sampling.collector import RolloutCollector
from dynenv_ros.learning.algo.policy import policy_step

EPISODE_PERIODS = 4     # episode_seconds 2.0 / 0.5 s per motion period


def _setup(targets=True, worlds=2, seed=3):
    torch.manual_seed(seed)
    env = SoccerVectorEnv(worlds, backend="inprocess", config={"players_per_team": 1, "episode_seconds": 2.0},
                          targets=targets)
    agent = DynEnvAgent()
    networks = TrainingNetworks(agent, horizon=3)
    collector = RolloutCollector(env, agent, np.arange(2), None, torch.Generator().manual_seed(seed), seed=seed)
    return env, networks, collector


@pytest.fixture(scope="module")
def rollout_setup():
    env, networks, collector = _setup()
    rollout = collector.collect(6)
    yield env, networks, collector, rollout
    env.close()


def _grads(networks, settings, rollout):
    networks.zero_grad(set_to_none=True)
    tensors = rollout.as_tensors()
    from dynenv_ros.learning.algo.advantages import generalized_advantages
    adv, ret = generalized_advantages(tensors["rewards"], tensors["values"], tensors["episode_end"],
                                      tensors["truncated"], tensors["final_values"], settings.gamma,
                                      settings.gae_lambda)
    loss, _ = minibatch_loss(networks, tensors, torch.arange(rollout.robots), adv, ret, settings,
                              lambda *a: None)
    loss.backward()
    return {name: (p.grad is not None and bool(p.grad.abs().sum() > 0)) for name, p in networks.named_parameters()}


def _only(**on):
    base = dict(policy_coef=0.0, value_coef=0.0, entropy_coef=0.0, use_forward=False, use_rcm=False, use_inverse=False,
                use_ltp=False, use_localization=False, use_reconstruction=False)
    base.update(on)
    return UpdateSettings(**base)


def _touched(grads, prefix):
    return any(v for k, v in grads.items() if k.startswith(prefix))


def test_policy_loss_reaches_actor_and_encoder_not_critic(rollout_setup):
    _, networks, _, rollout = rollout_setup
    grads = _grads(networks, _only(policy_coef=1.0), rollout)
    assert _touched(grads, "agent.walk_head") and _touched(grads, "agent.objects.")
    assert _touched(grads, "agent.localization.")
    assert not _touched(grads, "agent.critic") and not _touched(grads, "curiosity.")


def test_value_loss_reaches_critic(rollout_setup):
    _, networks, _, rollout = rollout_setup
    grads = _grads(networks, _only(value_coef=1.0), rollout)
    assert _touched(grads, "agent.critic") and _touched(grads, "agent.objects.")
    assert not _touched(grads, "agent.walk_head") and not _touched(grads, "curiosity.")


def test_forward_rcm_inverse_ltp_reach_their_heads(rollout_setup):
    _, networks, _, rollout = rollout_setup
    grads = _grads(networks, _only(use_forward=True, use_rcm=True, forward_coef=1.0), rollout)
    assert _touched(grads, "curiosity.forward_model") and _touched(grads, "curiosity.rcm_attention")
    assert _touched(grads, "agent.objects.")           # through φ_t, the forward model's input
    assert not _touched(grads, "curiosity.inverse_model") and not _touched(grads, "curiosity.ltp")
    grads = _grads(networks, _only(use_inverse=True, inverse_coef=1.0), rollout)
    assert _touched(grads, "curiosity.inverse_model") and _touched(grads, "agent.localization.")
    assert not _touched(grads, "curiosity.forward_model")
    grads = _grads(networks, _only(use_ltp=True, ltp_coef=1.0), rollout)
    assert _touched(grads, "curiosity.ltp.") and _touched(grads, "curiosity.ltp_attention")
    assert not _touched(grads, "curiosity.rcm_attention") and not _touched(grads, "agent.critic")


def test_localization_and_reconstruction_reach_their_streams(rollout_setup):
    _, networks, _, rollout = rollout_setup
    grads = _grads(networks, _only(use_localization=True, self_supervised_coef=1.0), rollout)
    assert _touched(grads, "agent.pose_head") and _touched(grads, "agent.localization.")
    # the object stream takes the pose detached: localization must not train it
    assert not _touched(grads, "agent.objects.") and not _touched(grads, "agent.reconstruction")
    grads = _grads(networks, _only(use_reconstruction=True, self_supervised_coef=1.0), rollout)
    assert _touched(grads, "agent.reconstruction") and _touched(grads, "agent.objects.")
    assert not _touched(grads, "agent.pose_head")


def test_ppo_first_minibatch_has_ratio_one_and_no_clipping(rollout_setup):
    _, networks, _, rollout = rollout_setup
    logged = {}
    tensors = rollout.as_tensors()
    from dynenv_ros.learning.algo.advantages import generalized_advantages
    adv, ret = generalized_advantages(tensors["rewards"], tensors["values"], tensors["episode_end"],
                                      tensors["truncated"], tensors["final_values"], 0.99, 0.95)
    networks.eval()
    minibatch_loss(networks, tensors, torch.arange(rollout.robots), adv, ret, UpdateSettings(algorithm="ppo"),
                    lambda name, value: logged.setdefault(name, float(value)))
    assert abs(logged["approx_kl"]) < 1e-6
    assert logged["clip_fraction"] == 0.0


def test_episode_end_truncation_and_final_value(rollout_setup):
    env, networks, collector, rollout = rollout_setup
    # reset at t=0, 4 periods per episode: the episode ends with step 3 (time limit), observation 4 starts anew
    assert rollout.starts[0].all() and rollout.starts[4].all()
    assert not rollout.starts[1:4].any() and not rollout.starts[5:].any()
    assert rollout.episode_end[3].all() and rollout.truncated[3].all()
    assert not rollout.episode_end[[0, 1, 2, 4, 5]].any()
    assert (rollout.final_values[3] != 0).all() and (rollout.final_values[[0, 1, 2, 4, 5]] == 0).all()


def test_final_value_is_the_critic_at_the_final_observation():
    env, networks, collector = _setup(targets=False, worlds=1, seed=5)
    states, finals = [], []
    original_step = env.step

    def spy(actions):
        states.append(tuple(s.clone() for s in collector.acting.state))
        result = original_step(actions)
        finals.append(result.final_observations)
        return result
    env.step = spy
    rollout = collector.collect(EPISODE_PERIODS)
    final_obs = finals[EPISODE_PERIODS - 1][0]
    with torch.no_grad():
        # the state after the last step of the episode: what the collector carried into the final observation
        expected = policy_step(networks.agent, final_obs, collector_state_after_episode(rollout, networks, env))
    assert rollout.final_values[EPISODE_PERIODS - 1] == pytest.approx(expected.value.numpy(), abs=1e-5)
    env.close()


def collector_state_after_episode(rollout, networks, env):
    """Re-run the episode's observations step by step from a zero state (what the collector did)."""
    state = networks.agent.initial_state(rollout.robots)
    with torch.no_grad():
        for t in range(rollout.steps):
            obs = {k: v[t] for k, v in rollout.obs.items()}
            state = policy_step(networks.agent, obs, state).state
    return state


def test_rollout_observations_are_the_env_layout(rollout_setup):
    env, _, _, rollout = rollout_setup
    shapes = env.layout.shapes()
    for key, shape in shapes.items():
        assert rollout.obs[key].shape == (7, 4) + tuple(shape)
    assert rollout.targets["pose"].shape == (7, 4, 6)
    assert rollout.targets["robots"].shape == (7, 4, 1, 6)
    # seen-before is an OR over the episode so far, reset at the start of the next episode
    known = rollout.targets["ball_known"]
    assert (known[1:4] >= known[0:3]).all()
    np.testing.assert_array_equal(known[4], rollout.targets["ball_seen"][4])


def test_a2c_update_changes_parameters_and_reports_losses(rollout_setup):
    _, networks, _, rollout = rollout_setup
    optimizer = torch.optim.Adam(networks.parameters(), lr=1e-3)
    before = [p.detach().clone() for p in networks.agent.parameters()]
    stats = update(networks, optimizer, rollout.as_tensors(), UpdateSettings(use_localization=True,
                                                                            use_reconstruction=True))
    for key in ("policy_loss", "value_loss", "entropy", "forward_loss", "inverse_loss", "ltp_loss",
                "localization_loss", "reconstruction_loss", "explained_variance"):
        assert np.isfinite(stats[key]), key
    assert any(not torch.equal(b, p) for b, p in zip(before, networks.agent.parameters()))


def test_ltp_is_optimised_through_the_training_update():
    """DynEnv logged LTP but never optimised it (docs/original.md §12.12); here ``update`` — the trainer's own step —
    lowers it and moves the LTP predictors' weights."""
    env, networks, collector = _setup(targets=False, worlds=1, seed=8)
    rollout = collector.collect(4)
    env.close()
    optimizer = torch.optim.Adam(networks.parameters(), lr=1e-2)
    before = [p.detach().clone() for p in networks.curiosity.ltp.parameters()]
    settings = _only(use_ltp=True, ltp_coef=1.0)
    losses = [update(networks, optimizer, rollout.as_tensors(), settings)["ltp_loss"] for _ in range(40)]
    assert losses[-1] < 0.5 * losses[0]
    assert all(not torch.equal(b, p) for b, p in zip(before, networks.curiosity.ltp.parameters()))


def test_privileged_pose_seeding_is_off_by_default_and_trains_the_seeder_when_on():
    env, networks, collector = _setup(targets=True, worlds=1, seed=9)
    plain = collector.collect(3)
    assert plain.seed_pose is None
    seeded_collector = RolloutCollector(env, networks.agent, np.arange(2), None, torch.Generator().manual_seed(1),
                                        seed=9, pose_seeder=networks.seeded_state,
                                        seed_noise=np.zeros(6, np.float32), rng=np.random.default_rng(0))
    rollout = seeded_collector.collect(3)
    env.close()
    # noise 0: the seed is the true pose of the rollout's first observation
    np.testing.assert_allclose(rollout.seed_pose, rollout.targets["pose"][0], atol=1e-6)
    with torch.no_grad():
        expected = networks.seeded_state(torch.from_numpy(rollout.seed_pose))
    for got, want in zip(rollout.initial_state, expected):
        torch.testing.assert_close(got, want)
    grads = _grads(networks, _only(use_localization=True, self_supervised_coef=1.0), rollout)
    assert _touched(grads, "pose_seeder")
    grads = _grads(networks, _only(use_localization=True, self_supervised_coef=1.0), plain)
    assert not _touched(grads, "pose_seeder")


def test_intrinsic_reward_adds_its_own_advantage_and_trains_its_critic(rollout_setup):
    _, networks, _, rollout = rollout_setup
    from dynenv_ros.learning.algo.ppo import _intrinsic
    settings = UpdateSettings(intrinsic_reward_coef=1.0)
    advantages, returns, reward = _intrinsic(networks, rollout.as_tensors(), settings)
    ended = torch.from_numpy(rollout.episode_end)
    assert (reward[ended] == 0).all() and (reward[~ended] > 0).all()      # a squared error, never negative
    assert advantages.shape == reward.shape == returns.shape
    optimizer = torch.optim.Adam(networks.parameters(), lr=1e-3)
    before = [p.detach().clone() for p in networks.intrinsic_critic.parameters()]
    stats = update(networks, optimizer, rollout.as_tensors(), settings)
    assert stats["intrinsic_reward"] > 0 and np.isfinite(stats["intrinsic_value_loss"])
    assert all(not torch.equal(b, p) for b, p in zip(before, networks.intrinsic_critic.parameters()))
    # off (the paper): the intrinsic critic is untouched
    before = [p.detach().clone() for p in networks.intrinsic_critic.parameters()]
    update(networks, optimizer, rollout.as_tensors(), UpdateSettings())
    assert all(torch.equal(b, p) for b, p in zip(before, networks.intrinsic_critic.parameters()))
