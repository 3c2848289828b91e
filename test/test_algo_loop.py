"""The one training loop (``learning.algo.loop``): it learns from each experience its source gives, in order, counts
it before the source hears of the update, records it after, and stops on the source running dry, on ``until`` or at
the deadline — with a source and an update written out here (no network, no world)."""
from __future__ import annotations

import time

from dynenv_ros.learning.algo.experience import Experience, Progress
from dynenv_ros.learning.algo.loop import learn_from, train


class _ListSource:
    """Gives the experiences it holds, one a call, then None; writes down every call with what progress said."""

    def __init__(self, experiences):
        self.experiences = list(experiences)
        self.calls = []

    def next(self, progress, deadline):
        self.calls.append(("next", progress.updates))
        return self.experiences.pop(0) if self.experiences else None

    def learned(self, progress):
        self.calls.append(("learned", progress.updates, progress.env_steps, progress.episodes))

    def close(self):
        self.calls.append(("close",))


def _experiences():
    # env steps 6, 10, 4; episodes finished 1, 0, 2
    return [Experience({"name": "a"}, 6, [{"return": 1.0}]), Experience({"name": "b"}, 10),
            Experience({"name": "c"}, 4, [{"return": 2.0}, {"return": 3.0}], {"x": 1.0})]


def test_each_experience_is_learnt_counted_told_and_recorded_in_order():
    source, learnt, recorded = _ListSource(_experiences()), [], []

    def learn(experience):
        learnt.append((experience.batch["name"], progress.updates))      # before it is counted
        return {"loss": float(len(learnt))}

    progress = Progress()
    train(source, learn, progress, lambda e, stats, waited, took: recorded.append((e.batch["name"], stats["loss"])))
    assert learnt == [("a", 0), ("b", 1), ("c", 2)]
    assert recorded == [("a", 1.0), ("b", 2.0), ("c", 3.0)]
    # counted before the source is told: 6, 16, 20 env steps; 1, 1, 3 episodes
    assert source.calls == [("next", 0), ("learned", 1, 6, 1), ("next", 1), ("learned", 2, 16, 1), ("next", 2),
                            ("learned", 3, 20, 3), ("next", 3)]
    assert progress == Progress(env_steps=20, updates=3, episodes=3)


def test_until_and_the_deadline_stop_the_loop_and_learn_from_is_one_step():
    source = _ListSource(_experiences())
    progress = Progress()
    train(source, lambda e: {}, progress, until=lambda p: p.env_steps < 16)      # 6, then 16: stops after two
    assert progress.updates == 2 and source.calls[-1] == ("learned", 2, 16, 1)
    late = _ListSource(_experiences())
    train(late, lambda e: {}, Progress(), deadline=time.perf_counter() - 1.0)
    assert late.calls == []                                                      # past the deadline: never asked
    one = Progress(env_steps=100, updates=7)
    assert learn_from(Experience({}, 5, [{}]), lambda e: {"k": 2.0}, one, late) == {"k": 2.0}
    assert one == Progress(env_steps=105, updates=8, episodes=1) and late.calls == [("learned", 8, 105, 1)]
