"""Experience and weights really cross a network: a simulator group (sim + policy node) in one network namespace,
the trainer node in another, joined by a virtual Ethernet link; DDS restricted to UDP (no shared memory between
the two), discovery by static peers. Needs root (or CAP_NET_ADMIN) for ``ip netns``; skipped with the reason where
the machine does not allow it."""
from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import uuid

import pytest

from dynenv_ros.security.keys import generate_key_pair

NETNS_TIMEOUT_S = 150.0
pytestmark = pytest.mark.ros   # the nodes run as processes inside the namespaces


def _ip(*args: str) -> None:
    subprocess.run(["ip", *args], check=True, capture_output=True, text=True)


@pytest.fixture
def linked_namespaces():
    tag = uuid.uuid4().hex[:6]
    sim_ns, trainer_ns = f"dyn_sim_{tag}", f"dyn_trn_{tag}"
    veth_sim, veth_trainer = f"vs{tag}", f"vt{tag}"
    try:
        _ip("netns", "add", sim_ns)
        _ip("netns", "add", trainer_ns)
    except (OSError, subprocess.CalledProcessError) as error:
        for ns in (sim_ns, trainer_ns):
            subprocess.run(["ip", "netns", "del", ns], capture_output=True)
        reason = error.stderr.strip() if isinstance(error, subprocess.CalledProcessError) else str(error)
        pytest.skip(f"cannot create network namespaces here ({reason or 'ip netns failed'}): needs root or "
                    f"CAP_NET_ADMIN")
    try:
        _ip("link", "add", veth_sim, "type", "veth", "peer", "name", veth_trainer)
        _ip("link", "set", veth_sim, "netns", sim_ns)
        _ip("link", "set", veth_trainer, "netns", trainer_ns)
        for ns, dev, address in ((sim_ns, veth_sim, "10.213.7.1/24"), (trainer_ns, veth_trainer, "10.213.7.2/24")):
            _ip("-n", ns, "addr", "add", address, "dev", dev)
            _ip("-n", ns, "link", "set", dev, "up")
            _ip("-n", ns, "link", "set", "lo", "up")
            _ip("-n", ns, "route", "add", "224.0.0.0/4", "dev", dev)
        yield sim_ns, trainer_ns, veth_trainer
    finally:
        for ns in (sim_ns, trainer_ns):
            subprocess.run(["ip", "netns", "del", ns], capture_output=True)


def _start(ns: str, peer: str, module: str, log, *parameters: str) -> subprocess.Popen:
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="SUBNET", ROS_STATIC_PEERS=peer,
               FASTDDS_BUILTIN_TRANSPORTS="UDPv4", PYTHONUNBUFFERED="1")
    args = ["ip", "netns", "exec", ns, sys.executable, "-m", module, "--ros-args"]
    for parameter in parameters:
        args += ["-p", parameter]
    return subprocess.Popen(args, env=env, stdout=log, stderr=subprocess.STDOUT)


def _received_bytes(ns: str, dev: str) -> int:
    out = subprocess.run(["ip", "-n", ns, "-s", "link", "show", dev], check=True, capture_output=True,
                         text=True).stdout
    return int(re.search(r"RX:.*\n\s*(\d+)", out).group(1))


def test_experience_and_weights_cross_a_network_boundary(linked_namespaces, tmp_path):
    sim_ns, trainer_ns, trainer_dev = linked_namespaces
    run = tmp_path / "run"
    private, public = generate_key_pair(tmp_path / "keys")       # signed weights, as a deployment runs them
    logs = {name: open(tmp_path / f"{name}.log", "w") for name in ("sim", "policy", "trainer")}
    processes = [
        _start(trainer_ns, "10.213.7.1", "dynenv_ros.nodes.trainer_node", logs["trainer"], "players_per_team:=1",
               "sequence_length:=4", "batch_sequences:=2", "ppo_epochs:=1", "ppo_minibatches:=1",
               "variant:=baseline", f"run_dir:={run}", "max_minutes:=0.6", f"signing_key:={private}"),
        _start(sim_ns, "10.213.7.2", "dynenv_ros.nodes.sim_node", logs["sim"], "players_per_team:=1",
               "wait_for_subscribers:=2", "publish_markers:=false"),
        _start(sim_ns, "10.213.7.2", "policy_node.policy_node", logs["policy"], "players_per_team:=1",
               f"trusted_weights_keys:=[{public}]")]
    trainer = processes[0]
    try:
        trainer.wait(timeout=NETNS_TIMEOUT_S)
    finally:
        for process in processes:
            if process.poll() is None:
                process.terminate()
        for process in processes:
            try:
                process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                process.kill()
        for log in logs.values():
            log.close()
    texts = {name: (tmp_path / f"{name}.log").read_text() for name in logs}
    assert trainer.returncode == 0, texts["trainer"][-3000:]
    summary = json.loads((run / "summary.json").read_text())
    assert summary["updates"] >= 2 and summary["diagnostics"]["games"] == "1", summary
    assert summary["diagnostics"]["malformed"] == "0"
    # the policy node, in the other namespace, took the trainer's weights beyond the first version
    versions = [int(v) for v in re.findall(r"weights version (\d+) of run", texts["policy"])]
    assert versions and max(versions) >= 2, texts["policy"][-3000:]
    # and it crossed the link: the trainer's side received the experience over the veth (UDP only)
    assert _received_bytes(trainer_ns, trainer_dev) > 200_000
