"""``dynenv-keys``: make and inspect the keys of issue 27 (docs/ros_graph.md, "Keys on a robot").

    dynenv-keys generate [DIR]      # trainer.key (0600) + trainer.pub; DIR: $DYNENV_KEYS_DIR or ~/.config/dynenv_ros/keys
    dynenv-keys show FILE           # the key id of a .pub or .key file (what announcements carry in key_id)
    dynenv-keys team-secret FILE    # a team's shared secret for authenticated actions (security.action_auth)

Errors are one line on stderr and exit status 2; nothing is ever overwritten.
"""
from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from dynenv_ros.security.keys import KeyFileError, default_keys_dir, generate_key_pair, key_id, load_private_key, \
    load_public_key


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="dynenv-keys", description="Keys for signed weights and authenticated "
                                     "actions (docs/ros_graph.md, 'Keys on a robot').")
    commands = parser.add_subparsers(dest="command", required=True)
    generate = commands.add_parser("generate", help="write a new Ed25519 pair trainer.key (0600) and trainer.pub")
    generate.add_argument("directory", nargs="?", type=Path, default=None,
                          help="where (default: $DYNENV_KEYS_DIR, else ~/.config/dynenv_ros/keys)")
    show = commands.add_parser("show", help="print the key id of a public (.pub) or private (.key) key file")
    show.add_argument("file", type=Path)
    secret = commands.add_parser("team-secret", help="write a team's shared secret for authenticated actions")
    secret.add_argument("file", type=Path)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    try:
        if args.command == "generate":
            private, public = generate_key_pair(args.directory or default_keys_dir())
            print(f"key {key_id(load_public_key(public))}: private {private} (mode 0600, keep it on the trainer's "
                  f"machine), public {public} (copy it to the robots)")
        elif args.command == "show":
            suffix = args.file.suffix
            key = (load_private_key(args.file).public_key() if suffix == ".key"
                   else load_public_key(args.file))
            print(key_id(key))
        else:
            try:
                from dynenv_ros.security.action_auth import write_team_secret
            except ImportError as error:
                raise KeyFileError(f"team secrets are not available: {error}") from None
            write_team_secret(args.file)
            print(f"team secret written to {args.file}")
    except (KeyFileError, ValueError, OSError) as error:
        print(f"dynenv-keys: error: {error}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
