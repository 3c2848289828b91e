"""Policies kept at fixed env-step marks: ``kept_policies/step_<env steps, 12 digits>.safetensors`` in a run folder.

Why: a run's end is not always its best, and its rolling checkpoints (``keep_checkpoints``) are deleted as it goes,
so a choice "the run's best copy on the validation games" needs copies that stay, taken at marks stated before the
run rather than whenever a wall-clock checkpoint happened to fall. ``keep_policy_every_env_steps: N`` keeps one each
time the learner's env steps pass a multiple of N; the file is a policy file like any other (``dynenv-eval`` and the
policy node load it), its meta adding ``kept_at_mark`` (the multiple passed; the file's name carries the env steps
at which it was written, the first update at or past the mark). A resumed run keeps the marks it had not passed at
its checkpoint; a mark passed after that checkpoint and before a kill is passed again and its file replaced.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

from dynenv_ros.agent.checkpoint import save_policy

FOLDER = "kept_policies"


def kept_policy_path(run_dir: str | Path, env_steps: int) -> Path:
    return Path(run_dir) / FOLDER / f"step_{env_steps:012d}.safetensors"


class KeptPolicies:
    """Says after each update whether a mark was passed, and writes the policy then."""

    def __init__(self, every: int, env_steps: int) -> None:
        if isinstance(every, bool) or not isinstance(every, int) or every < 1:
            raise ValueError(f"every must be a positive number of env steps, got {every!r}")
        self.every = every
        self.next_mark = (env_steps // every + 1) * every       # the first mark not yet passed

    def after_update(self, run_dir: str | Path, env_steps: int, agent: Any, meta: Mapping[str, Any]) -> Path | None:
        """Write the policy when ``env_steps`` reached the next mark (one file even where an update passed several);
        the path written, else None."""
        if env_steps < self.next_mark:
            return None
        mark = env_steps // self.every * self.every
        self.next_mark = mark + self.every
        path = kept_policy_path(run_dir, env_steps)
        path.parent.mkdir(parents=True, exist_ok=True)
        save_policy(agent, path, {**meta, "kept_at_mark": mark})
        return path
