"""``dynenv-keys``: make and inspect the keys of issue 27, and sign an operator's requests and files (issue 43;
docs/ros_graph.md, "Keys on a robot" and "Who may command a node").

    dynenv-keys generate [DIR]      # trainer.key (0600) + trainer.pub; DIR: $DYNENV_KEYS_DIR or ~/.config/dynenv_ros/keys
    dynenv-keys operator [DIR]      # operator.key (0600) + operator.pub: signs requests and policy files
    dynenv-keys show FILE           # the key id of a .pub or .key file (what announcements carry in key_id)
    dynenv-keys team-secret FILE    # a team's shared secret for authenticated actions (security.action_auth)
    dynenv-keys sign-file FILE      # FILE.sig: a detached signature LoadPolicy accepts
    dynenv-keys sign-request SERVICE TYPE [VALUES]   # the request with its signature, as YAML for ros2 service call
    dynenv-keys call SERVICE TYPE [VALUES]           # ros2 service call, signed (the venv has no ros2cli)

``--key`` picks the operator's private key (default: operator.key in the keys folder). A signed request is good for
30 s, once, for the node that owns SERVICE (``/policy_node/load_policy`` -> ``/policy_node``; ``--node`` to say
otherwise). Errors are one line on stderr and exit status 2; ``call``: 1 when the service does not appear or answer,
3 when it answers with success false (the reply says why). No key file is ever overwritten.

It lives in ``ros`` because ``sign-request`` and ``call`` build and send ROS messages; the keys and signatures it
uses stay in the ROS-free ``security`` (the contracts in .importlinter).
"""
from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from dynenv_ros.security.keys import (OPERATOR_NAME, KeyFileError, default_keys_dir, generate_key_pair, key_id,
                                      load_private_key, load_public_key)


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="dynenv-keys", description="Keys for signed weights, signed operator "
                                     "requests and authenticated actions (docs/ros_graph.md, 'Keys on a robot').")
    commands = parser.add_subparsers(dest="command", required=True)
    generate = commands.add_parser("generate", help="write a new Ed25519 pair trainer.key (0600) and trainer.pub")
    generate.add_argument("directory", nargs="?", type=Path, default=None,
                          help="where (default: $DYNENV_KEYS_DIR, else ~/.config/dynenv_ros/keys)")
    operator = commands.add_parser("operator", help="write a new Ed25519 pair operator.key (0600) and operator.pub "
                                   "(signs requests and policy files; give the robots operator.pub)")
    operator.add_argument("directory", nargs="?", type=Path, default=None,
                          help="where (default: $DYNENV_KEYS_DIR, else ~/.config/dynenv_ros/keys)")
    show = commands.add_parser("show", help="print the key id of a public (.pub) or private (.key) key file")
    show.add_argument("file", type=Path)
    secret = commands.add_parser("team-secret", help="write a team's shared secret for authenticated actions")
    secret.add_argument("file", type=Path)
    sign_file = commands.add_parser("sign-file", help="write FILE.sig, a detached signature of a policy file")
    sign_file.add_argument("file", type=Path)
    _key_option(sign_file)
    for name, text in (("sign-request", "print a service request with the operator's signature, as YAML for "
                                        "`ros2 service call SERVICE TYPE \"$(dynenv-keys sign-request …)\"`"),
                       ("call", "sign a service request and call the service (ros2 service call, signed)")):
        command = commands.add_parser(name, help=text)
        command.add_argument("service", help="the service, e.g. /policy_node/load_policy")
        command.add_argument("type", help="its type, e.g. dynenv_msgs/srv/LoadPolicy")
        command.add_argument("values", nargs="?", default="{}", help="request fields as YAML (default: {})")
        command.add_argument("--node", default="", help="the node the request is for (fully qualified; default: "
                                                        "the service's node)")
        _key_option(command)
        if name == "call":
            command.add_argument("--timeout", type=float, default=10.0, help="seconds to wait for the service and "
                                                                             "its answer")
    return parser


def _key_option(command: argparse.ArgumentParser) -> None:
    command.add_argument("--key", type=Path, default=None, help="the operator's private key (default: "
                                                                "operator.key in $DYNENV_KEYS_DIR or "
                                                                "~/.config/dynenv_ros/keys)")


def _operator_key(path: Path | None):
    return load_private_key(path or default_keys_dir() / f"{OPERATOR_NAME}.key")


def split_service(service: str, node: str = "") -> tuple[str, str, str]:
    """(service as called, the target node's fully qualified name, the service's name relative to it):
    ``policy_node/load_policy`` -> (``/policy_node/load_policy``, ``/policy_node``, ``load_policy``)."""
    full = service if service.startswith("/") else "/" + service
    owner, _, short = full.rpartition("/")
    if not short or not (node or owner):
        raise ValueError(f"service {service!r}: name it with its node, e.g. /policy_node/load_policy")
    target = node or owner
    if not target.startswith("/"):
        raise ValueError(f"--node {node!r} must be fully qualified (e.g. /policy_node)")
    return full, target, short


def signed_request(args: argparse.Namespace, sign: bool = True) -> tuple[str, Any, Any, Any]:
    """(service, service class, request — signed now unless ``sign`` is false —, the signing function) from the
    command line."""
    from dynenv_ros.ros.operator_gate import sign_message
    from dynenv_ros.ros.service_call import CallError, request_from_yaml
    full, target, short = split_service(args.service, args.node)
    private = _operator_key(args.key)
    try:
        kind, request = request_from_yaml(args.type, args.values)
    except CallError as error:
        raise ValueError(str(error).splitlines()[0]) from None
    if "signature" not in request.get_fields_and_field_types():
        raise ValueError(f"{args.type} has no signature field: its server does not check signatures")
    def signer(unsigned: Any) -> Any:
        return sign_message(unsigned, private, target, short)
    return full, kind, signer(request) if sign else request, signer


def main(argv: Sequence[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    try:
        if args.command in ("generate", "operator"):
            name = "trainer" if args.command == "generate" else OPERATOR_NAME
            private, public = generate_key_pair(args.directory or default_keys_dir(), name)
            where = "the trainer's machine" if name == "trainer" else "the operator's machine"
            print(f"key {key_id(load_public_key(public))}: private {private} (mode 0600, keep it on {where}), "
                  f"public {public} (copy it to the robots)")
        elif args.command == "show":
            suffix = args.file.suffix
            key = (load_private_key(args.file).public_key() if suffix == ".key"
                   else load_public_key(args.file))
            print(key_id(key))
        elif args.command == "team-secret":
            try:
                from dynenv_ros.security.action_auth import write_team_secret
            except ImportError as error:
                raise KeyFileError(f"team secrets are not available: {error}") from None
            write_team_secret(args.file)
            print(f"team secret written to {args.file}")
        elif args.command == "sign-file":
            from dynenv_ros.security.operator_requests import sign_file
            key = _operator_key(args.key)
            if not args.file.expanduser().is_file():
                raise ValueError(f"{args.file} is not a file")
            written = sign_file(key, args.file)
            print(f"{written}: {args.file} signed by key {key_id(key.public_key())}")
        elif args.command == "sign-request":
            import yaml

            from dynenv_ros.ros.service_call import as_plain
            _, _, request, _ = signed_request(args)
            print(yaml.safe_dump(as_plain(request), default_flow_style=True, width=10**6).strip())
        else:
            return _call(args)
    except (KeyFileError, ValueError, OSError) as error:
        print(f"dynenv-keys: error: {error}", file=sys.stderr)
        return 2
    return 0


def _call(args: argparse.Namespace) -> int:
    import yaml

    from dynenv_ros.ros.service_call import as_plain, call
    full, kind, request, signer = signed_request(args, sign=False)
    key = key_id(_operator_key(args.key).public_key())
    print(f"requester: making a request to {full} signed by key {key}")
    response, why = call(full, kind, request, args.timeout, prepare=signer)      # signed once the service is there
    if response is None:
        print(f"dynenv-keys: {why}", file=sys.stderr)
        return 1
    print("response:")
    print(yaml.safe_dump(as_plain(response), sort_keys=False).rstrip())
    return 3 if getattr(response, "success", True) is False else 0


if __name__ == "__main__":
    raise SystemExit(main())
