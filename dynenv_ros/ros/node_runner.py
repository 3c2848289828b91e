"""The Jazzy main() idiom shared by every node: init, spin, clean shutdown on SIGINT/SIGTERM, exit status."""
from __future__ import annotations

import contextlib
import os
import sys
import tempfile
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import rclpy
from rclpy.context import Context
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import uninstall_signal_handlers


class NodeExit(Exception):
    """Raised from a callback to stop spinning with an exit status (e.g. a self-check that finished)."""

    def __init__(self, status: int) -> None:
        super().__init__(status)
        self.status = status


def run_node(make_node: Callable[[], Node], args: Sequence[str] | None = None) -> int:
    """Create the node, spin it until shutdown or NodeExit, and return the process exit status. ``-h``/``--help``
    (before any ``--ros-args``) prints the node's parameters instead and returns 0 without starting ROS."""
    if wants_help(sys.argv[1:] if args is None else args):
        print(parameter_help(make_node))
        return 0
    try:
        args = resolve_params_files(sys.argv if args is None else list(args))
    except FileNotFoundError as error:
        print(f"parameter error: {error}", file=sys.stderr, flush=True)
        return 2
    rclpy.init(args=args)
    node = None
    status = 0
    try:
        try:
            node = make_node()
            refuse_unknown_overrides(node)
            executor = SingleThreadedExecutor()
            executor.add_node(node)
            executor.spin()
        except NodeExit as stop:
            status = stop.status
        except ParameterException as error:  # out of range or wrong type: refuse with the reason
            print(f"parameter error: {error}", file=sys.stderr, flush=True)
            status = 2
        except ExternalShutdownException:
            pass
        except Exception as error:
            # A signal during start-up or a callback: what ran next found the context already shut down. A stop
            # asked for, not a failure; any other error is one.
            if type(error).__name__ != "RCLError" or rclpy.ok():
                raise
    except KeyboardInterrupt:
        # SIGINT: rclpy's signal thread shuts the context down, and Python raises KeyboardInterrupt in this thread
        # at its next check, which may fall in spin or in one of the handlers above (after an RCLError).
        pass
    finally:
        stop_cleanly(node)
    return status


def stop_cleanly(node: Node | None) -> None:
    """Destroy ``node``, shut rclpy down and give the signals back, each step carried out even if the SIGINT that
    asked for the stop is delivered to Python (KeyboardInterrupt) in the middle of it."""
    steps = [node.destroy_node] if node is not None else []
    # rclpy.shutdown would also uninstall rclpy's signal handlers, try_shutdown does not: without them a signal
    # after the node is gone gets Python's own handling, and rclpy's signal thread does not outlive the node.
    for step in (*steps, shutdown_quietly, uninstall_signal_handlers):
        for _attempt in range(3):
            try:
                step()
                break
            except KeyboardInterrupt:
                continue


def shutdown_quietly(context: Context | None = None) -> None:
    """Shut ``context`` (default: rclpy's) down unless it is already. rclpy checks, then shuts down; its
    signal-handling thread can shut the context down in between, and the second shutdown raises RCLError."""
    try:
        rclpy.try_shutdown(context=context)
    except Exception as error:
        if type(error).__name__ != "RCLError" or (context.ok() if context is not None else rclpy.ok()):
            raise


PACKAGE = "dynenv_ros"


def params_file_candidates(given: str) -> list[Path]:
    """Where ``--params-file GIVEN`` may be: as given (from the working directory), else — a relative path such as
    ``config/sim_2v2_realistic.yaml``, or a bare file name — in the package's source tree or its installed share
    directory (``<prefix>/share/dynenv_ros/config``), as ``ros2 run`` users expect of a package's presets."""
    path = Path(given).expanduser()
    if path.is_absolute():
        return [path]
    roots = [Path(__file__).resolve().parents[2], Path(sys.prefix) / "share" / PACKAGE]
    relative = [path] if path.parts[:1] == ("config",) else [path, Path("config") / path]
    return [path, *[root / r for root in roots for r in relative]]


def resolve_params_files(args: list[str]) -> list[str]:
    """``args`` with each ``--params-file`` argument replaced by the first existing candidate
    (``params_file_candidates``); FileNotFoundError, one line naming where it looked, if there is none."""
    out = list(args)
    for k, word in enumerate(out[:-1]):
        if word == "--params-file":
            candidates = params_file_candidates(out[k + 1])
            found = next((c for c in candidates if c.is_file()), None)
            if found is None:
                raise FileNotFoundError(f"--params-file {out[k + 1]}: no such file here, in the package's config "
                                        f"folder or its share directory ({', '.join(map(str, candidates[1:]))})")
            out[k + 1] = str(found)
    return out


def refuse_unknown_overrides(node: Node) -> None:
    """A ``-p name:=value`` or params-file entry the node never declared would be ignored without a word (a typo such
    as ``player_per_team``): refused instead, naming the node's parameters. ``use_sim_time`` and the other
    parameters rclpy declares itself count as declared."""
    unknown = sorted(set(node._parameter_overrides) - set(node._parameters))
    if unknown:
        known = ", ".join(sorted(node._parameters))
        raise ParameterException(f"unknown parameter{'s' if len(unknown) > 1 else ''} {', '.join(unknown)} for "
                                 f"node {node.get_name()}; its parameters: {known}", unknown)


def wants_help(args: Sequence[str]) -> bool:
    """``-h`` or ``--help`` among the node's own arguments (ROS arguments follow ``--ros-args``)."""
    own = list(args)[:list(args).index("--ros-args")] if "--ros-args" in args else list(args)
    return "-h" in own or "--help" in own


class _DeclarationsDone(Exception):
    """Raised by the stand-in Node at the node's first call that is not about parameters: declarations are over."""


_PARAMETER_CALLS = ("declare_parameter", "declare_parameters", "get_parameter", "get_parameters", "has_parameter",
                    "get_logger", "get_name", "get_namespace", "add_on_set_parameters_callback")


@contextlib.contextmanager
def _stand_in_node(found: list[tuple[str, Any, Any]], names: list[str]) -> Iterator[None]:
    """Make rclpy's Node a recorder of parameter declarations (no context, no DDS), for the time of the block.

    Each declaration is recorded as (name, default, descriptor) and answered with its default; any other Node
    call (a publisher, a timer, a graph query) ends the collection with ``_DeclarationsDone``.
    """
    from rclpy.logging import get_logger
    from rclpy.parameter import Parameter

    values: dict[str, Any] = {"use_sim_time": False}

    def init(self: Node, node_name: str, *_: Any, **__: Any) -> None:
        self._parameter_overrides = {}
        self._help_name = node_name
        names.append(node_name)

    def declare_parameter(self: Node, name: str, value: Any = None, descriptor: Any = None,
                          ignore_override: bool = False) -> Parameter:
        found.append((name, value, descriptor))
        values[name] = value
        return Parameter(name, value=value)

    def declare_parameters(self: Node, namespace: str, parameters: list, ignore_override: bool = False) -> list:
        prefix = f"{namespace}." if namespace else ""
        return [declare_parameter(self, prefix + p[0], *p[1:]) for p in parameters]

    def get_parameter(self: Node, name: str) -> Parameter:
        return Parameter(name, value=values.get(name))

    def done(*_: Any, **__: Any) -> None:
        raise _DeclarationsDone

    replacements: dict[str, Any] = {
        "__init__": init, "declare_parameter": declare_parameter, "declare_parameters": declare_parameters,
        "get_parameter": get_parameter, "get_parameters": lambda self, names: [get_parameter(self, n) for n in names],
        "has_parameter": lambda self, name: name in values, "get_logger": lambda self: get_logger(self._help_name),
        "get_name": lambda self: self._help_name, "get_namespace": lambda self: "/",
        "add_on_set_parameters_callback": lambda self, callback: None}
    saved = dict(vars(Node))
    for name, attribute in saved.items():
        if name in replacements:
            setattr(Node, name, replacements[name])
        elif not name.startswith("__") and (callable(attribute) or isinstance(attribute, property)):
            setattr(Node, name, property(done) if isinstance(attribute, property) else done)
    try:
        yield
    finally:
        for name in replacements:
            setattr(Node, name, saved[name])
        for name, attribute in saved.items():
            if not name.startswith("__"):
                setattr(Node, name, attribute)


@dataclass
class Declarations:
    """What a node's constructor declares, collected without ROS (``collect_declarations``)."""
    node_name: str | None
    parameters: list[tuple[str, Any, Any]]      # (name, default, ParameterDescriptor or None)
    stopped_by: str | None = None               # the error a constructor raised with every default, if any


def collect_declarations(make_node: Callable[[], Node]) -> Declarations:
    """Run the node's constructor against a stand-in Node until its first call that is not about parameters.

    It runs in a temporary working directory, so a default relative output path cannot leave anything behind.
    Used by ``--help`` and by the test that checks the parameters the docs show.
    """
    found: list[tuple[str, Any, Any]] = []
    names: list[str] = []
    stopped_by = None
    with tempfile.TemporaryDirectory() as scratch, _stand_in_node(found, names):
        cwd = os.getcwd()
        os.chdir(scratch)
        try:
            make_node()
        except _DeclarationsDone:
            pass
        except Exception as error:   # a constructor that needs more than its defaults: what was declared counts
            stopped_by = f"{type(error).__name__}: {error}"
        finally:
            os.chdir(cwd)
    return Declarations(names[0] if names else None, found, stopped_by)


def parameter_help(make_node: Callable[[], Node]) -> str:
    """The node's parameters (name, type, default, description, range or choices, read-only) as text."""
    declarations = collect_declarations(make_node)
    found = list(declarations.parameters)
    if declarations.stopped_by:
        found.append(("(with every default the node stops here)", None, declarations.stopped_by))
    lines = ["parameters (set with --ros-args -p NAME:=VALUE or --params-file FILE):"]
    for name, default, descriptor in found:
        if isinstance(descriptor, str):
            lines.append(f"  {name}: {descriptor}")
            continue
        if isinstance(default, list) and all(v == "" for v in default):
            default = []                 # declare_str_list declares [""] for an empty list (rclpy needs a type)
        lines.append(f"  {name} (default {default!r}{_constraints(descriptor)}): "
                     f"{getattr(descriptor, 'description', '') or 'no description'}")
    return "\n".join(lines)


def _constraints(descriptor: Any) -> str:
    if descriptor is None:
        return ""
    parts = []
    for bounds in list(descriptor.integer_range) + list(descriptor.floating_point_range):
        parts.append(f"{bounds.from_value}..{bounds.to_value}")
    if descriptor.additional_constraints:
        parts.append(descriptor.additional_constraints)
    if descriptor.read_only:
        parts.append("read-only")
    return "; " + "; ".join(parts) if parts else ""
