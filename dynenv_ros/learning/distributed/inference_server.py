"""The inference server of the asynchronous runner (``inference: server``, Sample Factory's design): one process
runs the acting forward of every rollout worker's learning robots as one batch on ``device`` (a GPU with ``cuda``),
keeps their recurrent states and draws their actions, while the workers only step their worlds.

Why a process of its own, not a thread of the learner: the learner's update and the server's forwards are both
thousands of small torch calls a second, each dispatched by Python; in one process they would take turns at one
interpreter lock, and the server would answer the workers late whenever the learner is busy, which is always. A
process reads the weights from the same shared block the workers read (``SharedWeights``, a seqlock: never a torn
copy, where a thread would need a lock around the learner's optimizer step or a copy of its weights), and it fails
on its own: its death is an exit code the pool reports, not a dead thread inside the learner. The costs: one more
process (a core, and a second CUDA context on a GPU), and each period's observations are copied into shared memory
once more than when a worker acts itself.

How a period travels. Each worker has one pipe to the server and one set of arrays in shared memory (``SharedArrays``
made by the server when the worker registers, unlinked when it goes); the pipe carries only small messages:

    worker → server    ("register", seed, layout spec, spec)   → ("arrays", names): the worker's request and answer
                       ("step", last, want_state, teacher)      observations, starts (teacher actions, driven rows)
                       ("final", n)                             the final observations of n truncated robots
                       ("seed",)                                seed poses (privileged pose seeding)
    server → worker    ("done", version)                        the answer is in the arrays; version: the weights'
                       ("error", reason)                        update count
    learner → server   ("attach", worker, connection)           the server's end of a (new) worker's pipe
                       ("stop",)
    server → learner   ("error", reason, traceback)             it failed and stops

Batching (``BatchedActing``): the server waits until a worker asks, then serves every request waiting at that
moment; the step requests of one layout become one forward. Each worker's actions are drawn by a generator seeded as
the worker's own would be (``RolloutWorker``), over that worker's rows alone: the draws a worker would make itself.
A rollout's ``version`` is the oldest weights any of its periods was served with (the server loads new weights as
they are published, so a rollout may span two versions; the policy-lag bound holds for the oldest).

Faults: a dead worker closes its pipe; the server forgets its state and arrays, and its replacement registers
afresh (new seeds, new episodes, as with ``inference: worker``). A dead or failed server ends every worker's wait
(``InferenceServerError``, end of file on its pipe), and the pool stops the run with the server's reason. The server
dies with the learner (``child_process.die_with_parent``).
"""
from __future__ import annotations

import traceback
from dataclasses import dataclass
from multiprocessing.connection import Connection, wait
from types import SimpleNamespace
from typing import Any, Mapping, Sequence

import numpy as np
import torch

from dynenv_ros.agent.network import POSE_SIZE, State
from dynenv_ros.core.shared_arrays import AttachedArrays, SharedArrays
from dynenv_ros.learning.algo.networks import TrainingNetworks, make_agent
from dynenv_ros.learning.algo.policy import action_width, head_outputs, policy_step, reset_state
from dynenv_ros.learning.config import TrainConfig
from dynenv_ros.learning.distributed.child_process import die_with_parent, one_line
from dynenv_ros.learning.distributed.shared_weights import AttachedWeights
from dynenv_ros.learning.sampling.acting import Acted, act_on

STOP_TIMEOUT_S = 5.0


class InferenceServerError(RuntimeError):
    """The inference server is gone or refused a request; the message is one line saying why."""


@dataclass
class StepRequest:
    """One worker's period (``Acting.step``'s arguments)."""
    worker: int
    obs: Mapping[str, np.ndarray]
    starts: np.ndarray
    last: bool
    want_state: bool = False
    teacher: np.ndarray | None = None
    driven: np.ndarray | None = None


@dataclass
class _Robots:
    """What the server keeps of one worker: its robots' recurrent state, its generator and its observations' layout."""
    state: State
    generator: torch.Generator
    layout_spec: Any


class BatchedActing:
    """Acting for the robots of many workers at once, transport-free: the server's core. Per worker (``add``) the
    recurrent states of its robots and its generator; ``step`` runs every request of one layout as one forward."""

    def __init__(self, networks: TrainingNetworks) -> None:
        self.networks, self.agent = networks, networks.agent
        self.device = next(networks.parameters()).device
        self.robots: dict[int, _Robots] = {}
        self.forwards = 0                    # forwards run, and the robots they carried (the batching achieved)
        self.forward_robots = 0

    def add(self, worker: int, seed: int, batch: int, layout_spec: Any) -> None:
        """A worker's ``batch`` robots, all at the start of an episode; ``seed``: its generator's."""
        state = tuple(s.to(self.device) for s in self.agent.initial_state(batch))
        self.robots[worker] = _Robots(state, torch.Generator().manual_seed(seed), layout_spec)   # type: ignore

    def forget(self, worker: int) -> None:
        self.robots.pop(worker, None)

    def _layout(self, worker: int) -> None:
        spec = self.robots[worker].layout_spec
        if spec is not None:
            self.agent.layout_spec = spec

    def seed(self, worker: int, pose: np.ndarray) -> None:
        self.robots[worker].state = self.networks.seeded_state(torch.from_numpy(pose).to(self.device))

    def final_values(self, worker: int, obs: Mapping[str, np.ndarray], rows: np.ndarray) -> np.ndarray:
        self._layout(worker)
        state = tuple(s[torch.from_numpy(rows).to(self.device)] for s in self.robots[worker].state)
        return policy_step(self.agent, obs, state).value.cpu().numpy()   # type: ignore[arg-type, no-any-return]

    def step(self, requests: Sequence[StepRequest]) -> list[Acted]:
        """Each request's outcome, in their order: requests whose observations share a layout and their shapes run
        as one forward, and each worker's actions are drawn from its own generator over its own rows."""
        out: list[Acted | None] = [None] * len(requests)
        groups: list[tuple[Any, list[int]]] = []
        for i, request in enumerate(requests):
            key = (self.robots[request.worker].layout_spec,
                   sorted((k, v.shape[1:], v.dtype.str) for k, v in request.obs.items()))
            for group_key, members in groups:
                if group_key == key:
                    members.append(i)
                    break
            else:
                groups.append((key, [i]))
        for _, members in groups:
            for i, acted in zip(members, self._forward([requests[i] for i in members])):
                out[i] = acted
        return out   # type: ignore[return-value]

    def _forward(self, requests: list[StepRequest]) -> list[Acted]:
        self._layout(requests[0].worker)
        states = [reset_state(self.robots[r.worker].state, torch.from_numpy(np.array(r.starts, bool)))
                  for r in requests]
        sizes = [len(r.starts) for r in requests]
        if len(requests) == 1:
            obs: Mapping[str, np.ndarray] = requests[0].obs
            state = states[0]
        else:
            obs = {k: np.concatenate([r.obs[k] for r in requests]) for k in requests[0].obs}
            state = tuple(torch.cat(parts) for parts in zip(*states))     # type: ignore[assignment]
        step = policy_step(self.agent, obs, state)
        self.forwards += 1
        self.forward_robots += sum(sizes)
        values = step.value.cpu().numpy()
        heads = {k: None if v is None else v.cpu() for k, v in vars(head_outputs(step)).items()}
        results, start = [], 0
        for request, size, begun in zip(requests, sizes, states):
            rows = slice(start, start + size)
            start += size
            acted = Acted(values[rows], start_state=begun if request.want_state else None)
            if not request.last:
                mine = SimpleNamespace(**{k: None if v is None else v[rows] for k, v in heads.items()})
                acted.actions, acted.log_probs = act_on(self.agent, mine, self.robots[request.worker].generator,
                                                        request.teacher, request.driven)
                self.robots[request.worker].state = tuple(s[rows] for s in step.state)   # type: ignore[assignment]
            results.append(acted)
        return results


# -- the worker's side ---------------------------------------------------------------------------------------------
def request_spec(obs: Mapping[str, np.ndarray], agent: Any, with_teacher: bool, seeding: bool
                 ) -> dict[str, tuple[tuple[int, ...], str]]:
    """The arrays a worker of these first observations (B robots leading) exchanges with the server: its request
    (``obs/<key>``, ``starts``, ``rows``; ``teacher``, ``driven``; ``seed_pose``) and the answer (``values``,
    ``actions``, ``log_probs``, ``state/<i>``)."""
    batch = len(next(iter(obs.values())))
    width, dtype = action_width(agent)
    spec = {f"obs/{k}": ((batch, *v.shape[1:]), v.dtype.str) for k, v in obs.items()}
    spec.update({"starts": ((batch,), "|b1"), "rows": ((batch,), "<i8"), "values": ((batch,), "<f4"),
                 "actions": ((batch, width), np.dtype(dtype).str), "log_probs": ((batch,), "<f4")})
    spec.update({f"state/{i}": ((batch, *s.shape[1:]), "<f4") for i, s in enumerate(agent.initial_state(1))})
    if with_teacher:
        spec.update({"teacher": ((batch, width), np.dtype(dtype).str), "driven": ((batch,), "|b1")})
    if seeding:
        spec["seed_pose"] = ((batch, POSE_SIZE), "<f4")
    return spec


class ServerActing:
    """A rollout worker's ``Acting`` on the inference server at the other end of ``conn``; registers at once.
    ``oldest``: the oldest weights version the server answered with since the caller last cleared it."""

    def __init__(self, conn: Connection, seed: int, agent: Any, obs: Mapping[str, np.ndarray], with_teacher: bool,
                 seeding: bool) -> None:
        self.conn = conn
        self.oldest: int | None = None
        self._states = len(agent.initial_state(1))
        spec = request_spec(obs, agent, with_teacher, seeding)
        names = self._call(("register", seed, getattr(agent, "layout_spec", None), spec))[1]
        self._attached = AttachedArrays(names)
        self.arrays = self._attached.arrays

    def _call(self, message: tuple[Any, ...]) -> tuple[Any, ...]:
        try:
            self.conn.send(message)
            answer: tuple[Any, ...] = self.conn.recv()
        except (EOFError, OSError):
            raise InferenceServerError("the inference server is gone (its pipe closed)") from None
        if answer[0] == "error":
            raise InferenceServerError(f"the inference server refused {message[0]!r}: {answer[1]}")
        if answer[0] == "done":
            self.oldest = answer[1] if self.oldest is None else min(self.oldest, answer[1])
        return answer

    def seed(self, pose: np.ndarray) -> None:
        self.arrays["seed_pose"][...] = pose
        self._call(("seed",))

    def step(self, obs: Mapping[str, np.ndarray], starts: np.ndarray, last: bool, want_state: bool = False,
             teacher: np.ndarray | None = None, driven: np.ndarray | None = None) -> Acted:
        arrays = self.arrays
        for key, value in obs.items():
            arrays[f"obs/{key}"][...] = value
        arrays["starts"][...] = starts
        with_teacher = teacher is not None and driven is not None
        if with_teacher:
            arrays["teacher"][...] = teacher
            arrays["driven"][...] = driven
        self._call(("step", last, want_state, with_teacher))
        acted = Acted(arrays["values"].copy())
        if want_state:
            acted.start_state = tuple(torch.from_numpy(arrays[f"state/{i}"].copy())   # type: ignore[assignment]
                                      for i in range(self._states))
        if not last:
            acted.actions, acted.log_probs = arrays["actions"].copy(), arrays["log_probs"].copy()
        return acted

    def final_values(self, obs: Mapping[str, np.ndarray], rows: np.ndarray) -> np.ndarray:
        n = len(rows)
        for key, value in obs.items():
            self.arrays[f"obs/{key}"][:n] = value
        self.arrays["rows"][:n] = rows
        self._call(("final", n))
        return self.arrays["values"][:n].copy()

    def close(self) -> None:
        self.arrays = {}
        self._attached.close()


# -- the server process --------------------------------------------------------------------------------------------
@dataclass
class _Client:
    conn: Connection
    arrays: SharedArrays | None = None


class _Server:
    """The server process's loop over its control pipe and its workers' pipes."""

    def __init__(self, cfg: TrainConfig, weights_names: dict[str, Any]) -> None:
        device = torch.device(cfg.device)
        if device.type == "cpu":
            torch.set_num_threads(1)            # one core, like a worker: intra-op threads would fight the others
        networks = TrainingNetworks(make_agent(cfg), cfg.ltp_horizon).to(device).eval()
        for parameter in networks.parameters():
            parameter.requires_grad_(False)
        self.weights = AttachedWeights(weights_names, networks)
        self.version = self.weights.load_into(networks, -1)
        self.acting = BatchedActing(networks)
        self.clients: dict[int, _Client] = {}

    def serve(self, control: Connection) -> None:
        """Until told to stop (or the learner is gone: end of file)."""
        while True:
            ready = wait([control] + [c.conn for c in self.clients.values()])
            if control in ready:
                message = control.recv()
                if message[0] == "stop":
                    return
                if message[0] == "attach":
                    self._forget(message[1])
                    self.clients[message[1]] = _Client(message[2])
            waiting: list[tuple[int, tuple[Any, ...]]] = []
            for worker, client in list(self.clients.items()):
                if client.conn not in ready:
                    continue
                try:
                    message = client.conn.recv()
                except (EOFError, OSError):          # the worker died or stopped
                    self._forget(worker)
                    continue
                if message[0] == "register":
                    self._register(worker, client, *message[1:])
                else:
                    waiting.append((worker, message))
            if waiting:
                self.version = self.weights.load_into(self.acting.networks, self.version)   # when newer
                with torch.inference_mode():
                    self._serve(waiting)

    def _register(self, worker: int, client: _Client, seed: int, layout_spec: Any,
                  spec: dict[str, tuple[tuple[int, ...], str]]) -> None:
        if client.arrays is not None:
            client.arrays.close()
        client.arrays = SharedArrays({k: (tuple(shape), np.dtype(dtype)) for k, (shape, dtype) in spec.items()})
        self.acting.add(worker, seed, spec["starts"][0][0], layout_spec)
        self._answer(worker, ("arrays", client.arrays.names()))

    def _serve(self, waiting: list[tuple[int, tuple[Any, ...]]]) -> None:
        steps: list[StepRequest] = []
        for worker, message in waiting:
            arrays = self.clients[worker].arrays.arrays              # type: ignore[union-attr]
            if message[0] == "step":
                _, last, want_state, with_teacher = message
                obs = {k[4:]: v for k, v in arrays.items() if k.startswith("obs/")}
                steps.append(StepRequest(worker, obs, arrays["starts"].copy(), last, want_state,
                                         arrays["teacher"].copy() if with_teacher else None,
                                         arrays["driven"].copy() if with_teacher else None))
            elif message[0] == "final":
                n = message[1]
                obs = {k[4:]: v[:n] for k, v in arrays.items() if k.startswith("obs/")}
                arrays["values"][:n] = self.acting.final_values(worker, obs, arrays["rows"][:n].copy())
            elif message[0] == "seed":
                self.acting.seed(worker, arrays["seed_pose"].copy())
        for request, acted in zip(steps, self.acting.step(steps)):
            arrays = self.clients[request.worker].arrays.arrays      # type: ignore[union-attr]
            arrays["values"][...] = acted.values
            if acted.start_state is not None:
                for i, part in enumerate(acted.start_state):
                    arrays[f"state/{i}"][...] = part.cpu().numpy()
            if acted.actions is not None:
                arrays["actions"][...] = acted.actions
                arrays["log_probs"][...] = acted.log_probs
        for worker, _ in waiting:
            self._answer(worker, ("done", self.version))

    def _answer(self, worker: int, message: tuple[Any, ...]) -> None:
        try:
            self.clients[worker].conn.send(message)
        except OSError:
            self._forget(worker)

    def _forget(self, worker: int) -> None:
        client = self.clients.pop(worker, None)
        self.acting.forget(worker)
        if client is not None:
            client.conn.close()
            if client.arrays is not None:
                client.arrays.close()

    def close(self) -> None:
        for worker in list(self.clients):
            self._forget(worker)
        self.weights.close()


def server_main(control: Connection, cfg_dict: dict[str, Any], weights_names: dict[str, Any]) -> None:
    """The server process: serve until told to stop; a failure is reported on ``control``, then it exits."""
    die_with_parent()
    server = None
    try:
        server = _Server(TrainConfig.from_dict(cfg_dict), weights_names)
        server.serve(control)
    except (EOFError, BrokenPipeError, ConnectionResetError):
        return                                  # the learner is gone or closed the pipe
    except BaseException as error:              # report, then stop: the pool stops the run
        try:
            control.send(("error", one_line(error), traceback.format_exc()))
        except OSError:
            pass
    finally:
        if server is not None:
            server.close()


# -- the learner's side --------------------------------------------------------------------------------------------
class InferenceServer:
    """The learner's handle on the server process (started here, with the published weights' block names):
    ``connect`` makes a worker's pipe to it, ``check`` raises ``InferenceServerError`` once it failed or ended."""

    def __init__(self, cfg: TrainConfig, weights_names: dict[str, Any], context: Any) -> None:
        self._context = context
        self.control, child = context.Pipe()
        self.process = context.Process(target=server_main, name="dynenv-inference", daemon=True,
                                       args=(child, cfg.to_dict(), weights_names))
        self.process.start()
        child.close()
        self.failure: str | None = None

    @property
    def pid(self) -> int:
        return int(self.process.pid)

    def connect(self, worker: int) -> Connection:
        """A new pipe for worker ``worker`` (its earlier one is dropped): the server's end goes to the server, the
        other is returned for the worker process."""
        ours, theirs = self._context.Pipe()
        try:
            self.control.send(("attach", worker, ours))
        except OSError:
            theirs.close()
            self.check(wait_s=1.0)
            raise InferenceServerError("the inference server is gone (its control pipe closed)") from None
        finally:
            ours.close()
        return theirs

    def check(self, wait_s: float = 0.0) -> None:
        """InferenceServerError when the server reported a failure or its process ended (``wait_s``: how long to
        wait for the process to end, when a worker already saw it go)."""
        if self.failure is None:
            try:
                while self.control.poll():
                    message = self.control.recv()
                    if message[0] == "error":
                        self.failure = f"the inference server failed: {message[1]}"
            except (EOFError, OSError):
                pass
        if self.failure is None:
            self.process.join(timeout=wait_s)
            if not self.process.is_alive():
                self.failure = f"the inference server died (exit code {self.process.exitcode})"
        if self.failure is not None:
            raise InferenceServerError(self.failure)

    def close(self) -> None:
        try:
            self.control.send(("stop",))
        except OSError:
            pass
        self.process.join(timeout=STOP_TIMEOUT_S)
        if self.process.is_alive():
            self.process.kill()
            self.process.join(timeout=STOP_TIMEOUT_S)
        self.control.close()
