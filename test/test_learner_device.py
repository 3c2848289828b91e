"""The learner follows its inputs' device: acting, sampling and one update create no tensor on torch's default
device. ``--device cuda`` failed on its first GPU run because ``torch.arange(N)`` (the default device, the CPU)
met a mask on the GPU. CI has no GPU, so the default device is set to ``meta`` while the trainer works on the
CPU: any tensor made without naming its device then lands on ``meta``, and mixing it with the CPU tensors raises
as mixing CPU and CUDA tensors does. (Module-level constants, made at import on the CPU, are outside this net;
docs/benchmarks.md records the GPU run that checks them.)"""
import pytest
import torch

from dynenv_ros.learning.algo.ppo import update
from dynenv_ros.learning.config import load_config
from dynenv_ros.learning.train_cli import preset_path
from dynenv_ros.learning.trainer import Trainer


@pytest.mark.parametrize("preset, overrides", [
    ("paper_a2c", []),                                              # A2C, pred: RCM, LTP, localization, recon
    ("ppo", ["variant=icm", "intrinsic_reward_coef=0.1"]),          # PPO minibatches, curiosity as a reward
    ("paper_a2c", ["privileged_pose_seeding=true"]),
    ("paper_a2c", ["teacher=chaser", "imitation_coef=1", "teacher_driven_worlds=1"]),
    ("driving_quick", []),
    ("driving_pred", ["action_mode=continuous"]),
])
def test_acting_and_an_update_make_no_tensor_on_the_default_device(tmp_path, preset, overrides):
    cfg = load_config(preset_path(preset), ["backend=inprocess", "num_envs=2", "rollout_length=6",
                                            "log_every_updates=1000000", "checkpoint_every_minutes=1000000",
                                            *overrides])
    trainer = Trainer(cfg, tmp_path / "run", progress=False)
    try:
        before = [p.detach().clone() for p in trainer.networks.parameters()]
        with torch.device("meta"):
            trainer.networks.eval()
            rollout = trainer.source.collector.collect(cfg.rollout_length)
            trainer.networks.train()
            stats = update(trainer.networks, trainer.optimizer, rollout.as_tensors(trainer.device),
                           trainer.settings, trainer.generator)
        assert all(p.device.type == "cpu" for p in trainer.networks.parameters())
        changed = sum(not torch.equal(a, p.detach()) for a, p in zip(before, trainer.networks.parameters()))
        assert changed > 0 and all(torch.isfinite(torch.tensor(v)) for v in stats.values())
    finally:
        trainer.close()
