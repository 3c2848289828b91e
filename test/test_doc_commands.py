"""Every command shown in README.md and docs/*.md works as written, as far as CI can run it.

What counts as a command:
- each command line of a fenced ``bash`` / ``sh`` / ``shell`` / ``console`` block (comments dropped, ``\\``
  continuations joined, ``for`` loops and ``VAR=...`` assignments of the block expanded: the loop body is checked
  for every value), and
- each inline code span that starts with an entry point (``make``, ``.venv/bin/…``, ``dynenv-…``, ``ros2 …``,
  ``python …``, ``pytest …``, optionally behind ``time`` / ``taskset -c N`` / ``VAR=value``); spans may run over a
  line break, ``\\|`` in tables is ``|``, and in inline spans ``a|b|c`` lists alternatives (each one is checked).

How each is checked (none starts a long job, none starts ROS):
- console scripts (setup.py's TOOLS, ``dynenv-…``): the script's own ``main`` is called with the documented
  arguments and stopped right after its argparse parser accepted them (an unknown option or subcommand, a bad choice
  or a missing argument fails); then what the command would check first is checked too (``dynenv-run``: the
  settings with their ``--set`` overrides, refused when unknown or unused by the graph; ``dynenv-train`` /
  ``dynenv-bench train``: the training config with its overrides; ``dynenv-eval``: policy names). Paths that other
  documented commands produce (``runs/…``) need not exist. Cheap commands whose inputs are in the repository are
  run for real (``--help``, ``dynenv-bag info`` / ``echo --limit`` on a bag of the repository) and must exit 0.
  An inline span that only names a program, a subcommand or an option (``dynenv-bag reindex``, ``dynenv-bench sim
  --noise``) is a mention: the names must exist.
- ``make T VAR=…``: T must be a target and VAR a variable of the Makefile; the target's recipe
  (``$(VENV_PY) -m …``) with the variables substituted is checked as the ``python -m`` command it runs.
- ``ros2 run dynenv_ros NODE …`` (and ``.venv/bin/NODE``, ``python -m <node module>``): NODE must be in setup.py's
  NODES; the ROS arguments must parse (rcl's own parser); every ``-p`` / ``--params-file`` parameter must be one the
  node declares (collected with node_runner's stand-in Node, as ``NODE --help`` does, without ROS) and its value
  must have the declared type and lie in the declared range / choices.
- ``ros2 service call NAME TYPE VALUES``: the type must import, VALUES must set its request's fields, and the node
  NAME names must create that service.
- ``python -m MODULE …`` / ``python SCRIPT …``: importable / existing, and the arguments accepted by its parser.
- ``pytest …`` (also through ``make test PYTEST_ARGS=…``): collected with ``--collect-only``; the selection must
  collect at least one test.
- anything else must be listed in SKIPPED_EXTERNAL (an external tool CI does not have) or SHELL_SYNTAX with the
  reason; ``test_every_doc_command_is_checked_or_listed`` fails for a documented command that is neither.
Placeholders (``<robot>``, ``DIR``, ``…``) are replaced by real values listed in PLACEHOLDERS.
"""
from __future__ import annotations

import argparse
import ast
import contextlib
import functools
import importlib
import importlib.util
import inspect
import io
import itertools
import os
import re
import runpy
import shlex
import subprocess
import sys
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from unittest import mock

import pytest
import yaml

REPO = Path(__file__).resolve().parent.parent
DOC_FILES = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]
SHELL_LANGUAGES = {"bash", "sh", "shell", "console", "zsh"}
# Inline code spans starting with one of these (after wrappers and VAR=value prefixes) are commands.
INLINE_ENTRY_POINTS = ("make ", ".venv/bin/", "dynenv-", "ros2 ", "python ", "python3 ", "pytest ")
WRAPPERS = {"time": 0, "taskset": 2, "nice": 0}   # a wrapper and how many of its own arguments follow it

# Commands CI cannot run, by their first words, and why. A documented command that is neither checked nor listed
# here fails test_every_doc_command_is_checked_or_listed.
SKIPPED_EXTERNAL: dict[tuple[str, ...], str] = {
    ("ros2", "bag"): "ros2cli's `ros2 bag` is not among the PyPI wheels this project runs on (dynenv-bag and the "
                     "bag tests cover our bags)",
    ("ros2", "security"): "sros2 (`ros2 security`) is not shipped by the PyPI wheels; docs/ros_graph.md says the "
                          "security set-up is not tested here",
    ("git",): "clones from a remote (network)",
    ("cd",): "the colcon-workspace route changes into ~/ws (outside the repository)",
    ("source",): "sources a ROS 2 install (/opt/ros/jazzy, a colcon install/) that CI does not have",
    ("pip",): "installs from the package index (network); the bootstrap installs the same lock",
    ("rosdep",): "installs system packages (apt, network) on a ROS 2 install; test/test_package_dependencies.py checks "
                 "the package.xml keys it resolves against the code's imports",
    ("colcon",): "the colcon workspace build; test/test_colcon_build.py runs exactly this build against the venv",
    ("make", "lock"): "re-resolves requirements.in into a throw-away venv from the package index (network, minutes)",
    (".venv/bin/ray", "start"): "starts a node of the user's Ray cluster (other machines); test/test_ray_cluster.py "
                                "starts a real head and second node with these options and the token auth",
}
# Shell syntax inside a block: no program runs. for/done/[ ... ] drive the expansion of the commands around them.
SHELL_SYNTAX: dict[str, str] = {
    "for": "loop header (its values expand the loop body)", "done": "loop end", "do": "loop body start",
    "[": "test (evaluated for the assignment that follows it)", "export": "environment setting",
}
# Inline spans that are prose, not commands (exact text) and why.
MENTIONS: dict[str, str] = {
    "pytest": "the dependency's name in the README's dependency table",
    "ros2 run": "the verb in prose ('Users `ros2 run` the simulator …', 'where `ros2 run` looks'), no node named",
}
# Placeholder -> the real value substituted to check the command ("a|b" checks both).
PLACEHOLDERS: dict[str, str] = {
    "<robot>": "team_a_0",
    "<suite>": "msgs|setup|sim|vector|ros|policy|train|soak",   # every suite of dynenv-bench
    "DIR": "runs/doc_commands/recording",   # dynenv-record --output DIR
    "S": "5",                               # dynenv-record --duration S
    "N": "2",                               # --players-per-team N
    "O": "partial|padded",                  # --observation O
    "RUN": "runs/quick",                    # RUN/policy.safetensors: a dynenv-train run directory
    "RUN_DIR": "runs/quick",
    "BAG": "bags/sample_2v2_realistic_30s",
    "FILE": "config/sim_2v2_realistic.yaml",
}
ELLIPSES = ("…", "...")   # a whole argument "…" stands for optional further arguments and is dropped


# --------------------------------------------------------------------------------------------------- extraction
@dataclass
class DocCommand:
    where: str                       # "docs/bags.md:42"
    text: str                        # as shown (continuations joined)
    inline: bool
    argvs: list[list[str]] = field(default_factory=list)   # every expansion, one simple command each

    def __repr__(self) -> str:
        return f"{self.where}: {self.text}"


class _Scanner:
    """Splits shell text into simple commands at ; && || (and | in blocks), outside quotes and $(( ))."""

    def __init__(self, pipes: bool) -> None:
        self.pipes = pipes

    def split(self, text: str) -> list[tuple[str, str]]:
        """[(statement, operator before it)], comments removed."""
        out: list[tuple[str, str]] = []
        current: list[str] = []
        op = ""
        quote = ""
        depth = 0
        i = 0
        while i < len(text):
            c = text[i]
            if quote:
                if c == quote:
                    quote = ""
                elif c == "\\" and quote == '"' and i + 1 < len(text):
                    current.append(c)
                    i += 1
                    c = text[i]
                current.append(c)
            elif c in "'\"":
                quote = c
                current.append(c)
            elif text.startswith("$((", i):
                depth += 1
                current.append("$((")
                i += 2
            elif depth and text.startswith("))", i):
                depth -= 1
                current.append("))")
                i += 1
            elif depth:
                current.append(c)
            elif c == "#" and (i == 0 or text[i - 1].isspace()):
                break
            elif text.startswith("&&", i) or text.startswith("||", i):
                out.append(("".join(current).strip(), op))
                op, current = text[i:i + 2], []
                i += 1
            elif c == ";" or (c == "|" and self.pipes):
                out.append(("".join(current).strip(), op))
                op, current = c, []
            else:
                current.append(c)
            i += 1
        out.append(("".join(current).strip(), op))
        return [(s, o) for s, o in out if s]


def _expand_variables(text: str, env: dict[str, str]) -> str:
    text = re.sub(r"\$\(\((.*?)\)\)", lambda m: str(_arithmetic(m.group(1), env)), text)
    text = re.sub(r"\$\{(\w+)\}", lambda m: env.get(m.group(1), ""), text)
    return re.sub(r"\$(\w+)", lambda m: env.get(m.group(1), ""), text)


def _arithmetic(expression: str, env: dict[str, str]) -> int:
    names = re.sub(r"[A-Za-z_]\w*", lambda m: env.get(m.group(0), "0") or "0", expression)
    if not re.fullmatch(r"[\d\s+\-*/%()]*", names):
        raise ValueError(f"cannot evaluate $(({expression}))")
    return int(eval(names.replace("/", "//")))   # digits and operators only, checked above


def _words(statement: str) -> list[str]:
    return shlex.split(statement, comments=False, posix=True)


@dataclass
class _Line:
    number: int
    text: str


def _logical_lines(lines: list[tuple[int, str]], console: bool) -> list[_Line]:
    out: list[_Line] = []
    pending: _Line | None = None
    for number, raw in lines:
        text = raw.rstrip()
        if pending is None:
            if console:
                if not text.lstrip().startswith("$ "):
                    continue   # output
                text = text.lstrip()[2:]
            if not text.strip() or text.lstrip().startswith("#"):
                continue
            pending = _Line(number, "")
        if text.endswith("\\"):
            pending.text += text[:-1] + " "
            continue
        pending.text += text
        out.append(pending)
        pending = None
    if pending is not None:
        out.append(pending)
    return out


def _run_block(lines: list[_Line], where: Callable[[int], str]) -> list[DocCommand]:
    """Interpret a shell block: for-loops, VAR=... assignments, `[ a = b ] &&`; each other simple command is
    recorded (with every loop value) under its line."""
    scanner = _Scanner(pipes=True)
    statements: list[tuple[int, str, str]] = []   # (line, statement, operator before it)
    for line in lines:
        for statement, op in scanner.split(line.text):
            while True:   # "do for S in ...", "then x": the keyword opens a body, the rest is a statement
                head, _, rest = statement.partition(" ")
                if head in ("do", "then", "else") and rest.strip():
                    statements.append((line.number, head, op))
                    statement, op = rest.strip(), ";"
                    continue
                break
            statements.append((line.number, statement, op))
    commands: dict[int, DocCommand] = {}

    def record(number: int, argv: list[str]) -> None:
        command = commands.setdefault(number, DocCommand(where(number), "", inline=False))
        command.argvs.append(argv)

    def execute(start: int, end: int, env: dict[str, str]) -> None:
        i = start
        skip_next = False
        while i < end:
            number, statement, op = statements[i]
            words = statement.split()
            if words[0] == "for":
                match = re.fullmatch(r"for\s+(\w+)\s+in\s+(.*)", statement)
                assert match, f"{where(number)}: cannot read the loop {statement!r}"
                body_start = i + 1
                if body_start < end and statements[body_start][1] == "do":
                    body_start += 1
                depth, j = 1, body_start
                while j < end:
                    if statements[j][1].split()[0] == "for":
                        depth += 1
                    elif statements[j][1] == "done":
                        depth -= 1
                        if depth == 0:
                            break
                    j += 1
                for value in _words(_expand_variables(match.group(2), env)):
                    execute(body_start, j, {**env, match.group(1): value})
                i = j + 1
                continue
            if skip_next and op == "&&":
                skip_next = False
                i += 1
                continue
            skip_next = False
            expanded = _expand_variables(statement, env)
            argv = _words(expanded)
            if argv and argv[0] == "[":   # [ a = b ] && ...: the statement after && runs only if it holds
                test = argv[1:-1] if argv[-1] == "]" else argv[1:]
                if len(test) == 3 and test[1] in ("=", "==", "!="):
                    skip_next = (test[0] == test[2]) == (test[1] == "!=")
            elif len(argv) == 1 and re.fullmatch(r"[A-Za-z_]\w*=.*", argv[0]):   # VAR=value
                key, _, value = argv[0].partition("=")
                env[key] = value
            record(number, argv)
            i += 1

    execute(0, len(statements), {})
    for line in lines:   # the text as shown, without its comment
        if line.number in commands:
            commands[line.number].text = " ".join(f"{op} {s}" if op else s for s, op in scanner.split(line.text))
    return [commands[n] for n in sorted(commands)]


def _strip_prefixes(argv: list[str]) -> list[str]:
    """Drop VAR=value prefixes and wrappers (time, taskset -c N)."""
    argv = list(argv)
    while True:
        if len(argv) > 1 and re.fullmatch(r"[A-Za-z_]\w*=.*", argv[0]):
            argv = argv[1:]
        elif argv and argv[0] in WRAPPERS:
            argv = argv[1 + WRAPPERS[argv[0]]:]
        else:
            return argv


def _alternatives(token: str) -> list[str]:
    """Inline `info|echo|render` -> each; `ARGS=a|b` -> ARGS=a, ARGS=b."""
    if "|" not in token:
        return [token]
    head = token[:token.index("|")]
    prefix = head[:head.rindex("=") + 1] if "=" in head else ""
    return [prefix + alt for alt in token[len(prefix):].split("|")]


def _substitute_placeholders(token: str) -> str:
    for name, value in PLACEHOLDERS.items():
        if name.startswith("<"):
            token = token.replace(name, value)
        else:
            token = re.sub(rf"(?<![\w.\-/]){re.escape(name)}(?![\w.\-])", value, token)
    return token


def _inline_argvs(text: str) -> list[list[str]]:
    argvs: list[list[str]] = []
    for statement, _ in _Scanner(pipes=False).split(text):
        try:
            words = _words(statement)
        except ValueError:
            words = statement.split()
        tokens = []
        for word in words:
            if word in ELLIPSES:
                continue
            word = word.removeprefix("[").removesuffix("]")   # usage syntax: [--topics …]
            if word in ELLIPSES or not word:
                continue
            tokens.append(_alternatives(_substitute_placeholders(word)))
        argvs.extend([list(combo) for combo in itertools.product(*tokens)])
    return argvs


def _is_inline_command(text: str) -> bool:
    try:
        words = _strip_prefixes(_words(text))
    except ValueError:
        return False
    return bool(words) and (" ".join(words) + " ").startswith(INLINE_ENTRY_POINTS)


def extract(path: Path, rel: str | None = None) -> list[DocCommand]:
    rel = rel or path.relative_to(REPO).as_posix()
    lines = path.read_text(encoding="utf-8").split("\n")
    commands: list[DocCommand] = []
    prose: list[str] = []   # the file with fenced blocks blanked (line numbers kept)
    block: list[tuple[int, str]] | None = None
    language = ""
    for number, line in enumerate(lines, 1):
        fence = re.match(r"^\s*(```+|~~~+)\s*([\w+-]*)", line)
        if fence and block is None:
            block, language = [], fence.group(2).lower()
            prose.append("")
            continue
        if fence and block is not None and not fence.group(2):
            if language in SHELL_LANGUAGES:
                logical = _logical_lines(block, console=language == "console")
                commands.extend(_run_block(logical, lambda n: f"{rel}:{n}"))
            block = None
            prose.append("")
            continue
        if block is not None:
            block.append((number, line))
            prose.append("")
        else:
            prose.append(line)
    text = "\n".join(prose)
    for match in re.finditer(r"(?<!`)`([^`]+?)`(?!`)", text):
        span = match.group(1)
        if "\n\n" in span:
            continue
        span = " ".join(span.replace("\\|", "|").split())
        if not _is_inline_command(span):
            continue
        number = text.count("\n", 0, match.start()) + 1
        commands.append(DocCommand(f"{rel}:{number}", span, inline=True, argvs=_inline_argvs(span)))
    commands.sort(key=lambda c: int(c.where.rsplit(":", 1)[1]))
    seen: dict[str, int] = {}
    for command in commands:   # unique ids: a second command on one line gets "#2"
        seen[command.where] = seen.get(command.where, 0) + 1
        if seen[command.where] > 1:
            command.where += f"#{seen[command.where]}"
    return commands


def all_doc_commands() -> list[DocCommand]:
    return [command for path in DOC_FILES for command in extract(path)]


# ------------------------------------------------------------------------------------------------ what exists
def _setup_list(name: str) -> dict[str, str]:
    tree = ast.parse((REPO / "setup.py").read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == name for t in node.targets):
            return {i.partition("=")[0].strip(): i.partition("=")[2].strip() for i in ast.literal_eval(node.value)}
    raise AssertionError(f"setup.py has no {name} list")


NODES = _setup_list("NODES")
TOOLS = _setup_list("TOOLS")


class DocCommandError(AssertionError):
    """The documented command would not work as written."""


def _load(target: str) -> Callable[..., Any]:
    module_name, _, function = target.partition(":")
    return getattr(importlib.import_module(module_name), function)


# --------------------------------------------------------------------------------------------- argparse CLIs
class _Parsed(BaseException):
    """Raised right after a parser accepted the arguments: the command itself never runs."""

    def __init__(self, namespace: argparse.Namespace) -> None:
        super().__init__()
        self.namespace = namespace


@dataclass
class ParseOutcome:
    namespace: argparse.Namespace | None
    exit_code: int | None
    message: str
    parser: argparse.ArgumentParser | None


@contextlib.contextmanager
def _stop_after_parse(holder: dict[str, Any]) -> Iterator[None]:
    original = argparse.ArgumentParser.parse_args

    def parse_args(self: argparse.ArgumentParser, args: Any = None, namespace: Any = None) -> Any:
        holder.setdefault("parser", self)
        raise _Parsed(original(self, args, namespace))

    with mock.patch.object(argparse.ArgumentParser, "parse_args", parse_args):
        yield


def parse_only(call: Callable[[], Any]) -> ParseOutcome:
    """Run ``call`` (a CLI main) until its argparse parser accepted or refused the arguments."""
    holder: dict[str, Any] = {}
    out, err = io.StringIO(), io.StringIO()
    try:
        with _stop_after_parse(holder), contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            call()
    except _Parsed as parsed:
        return ParseOutcome(parsed.namespace, None, "", holder.get("parser"))
    except SystemExit as stop:
        code = stop.code if isinstance(stop.code, int) else (0 if stop.code is None else 2)
        return ParseOutcome(None, code, (err.getvalue() + out.getvalue()).strip(), holder.get("parser"))
    raise DocCommandError("the command returned without parsing its arguments (it would have run)")


def _subcommands(parser: argparse.ArgumentParser | None) -> set[str]:
    if parser is None:
        return set()
    return {name for action in parser._actions if isinstance(action, argparse._SubParsersAction)
            for name in action.choices}


def _accept_mention(outcome: ParseOutcome, args: list[str], inline: bool) -> bool:
    """An inline span naming a program, its subcommand(s) or an option (not a runnable command): the names exist."""
    if not inline or outcome.exit_code != 2:
        return False
    if "the following arguments are required" in outcome.message and not any(a.startswith("-") for a in args):
        return all(a in _subcommands(outcome.parser) for a in args[:1]) and len(args) <= 1
    missing_value = re.search(r"argument (\S+?)(?:/\S+)?: expected (?:one|at least one) argument", outcome.message)
    return bool(missing_value and args and args[-1] == missing_value.group(1))


def _run(argv: list[str], timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run(argv, cwd=REPO, capture_output=True, text=True, timeout=timeout,
                          env={**os.environ, "PYTHONUNBUFFERED": "1"})


def _run_script(target: str, args: list[str]) -> None:
    module_name, _, function = target.partition(":")
    code = f"import sys; from {module_name} import {function} as f; sys.exit(f(sys.argv[1:]))"
    result = _run([sys.executable, "-c", code, *args])
    if result.returncode != 0:
        tail = (result.stderr or result.stdout).strip().splitlines()[-3:]
        raise DocCommandError(f"exit status {result.returncode}: {' | '.join(tail)}")


# what each tool checks before any work, after parsing
def _semantic_run(ns: argparse.Namespace) -> None:
    from dynenv_ros import main_job
    try:
        main_job.load_config(ns.config or main_job.default_config_path(), main_job.parse_overrides(ns.set))
    except main_job.ConfigError as error:
        raise DocCommandError(f"dynenv-run refuses the settings: {error}") from None


def _train_config(config: str, overrides: list[str]) -> None:
    from dynenv_ros.learning.config import ConfigError, load_config
    from dynenv_ros.learning.train_cli import preset_path
    try:
        load_config(preset_path(config), overrides)
    except (ConfigError, ValueError) as error:
        raise DocCommandError(f"the training config is refused: {error}") from None


def _semantic_train(ns: argparse.Namespace) -> None:
    if ns.resume:
        return   # the run directory is the output of another documented command
    overrides = list(ns.overrides) + ([f"seed={ns.seed}"] if ns.seed is not None else []) + \
        ([f"device={ns.device}"] if ns.device else [])
    _train_config(ns.config, overrides)


def _semantic_bench(ns: argparse.Namespace) -> None:
    if ns.repeat < 1:
        raise DocCommandError("--repeat must be at least 1")
    if ns.suite == "train":
        _train_config(ns.config, list(ns.overrides))


def _semantic_eval(ns: argparse.Namespace) -> None:
    from dynenv_ros.evaluation.soccer import TEAM_NAMES
    for flag in ("policy", "opponent"):
        spec = getattr(ns, flag, None)
        if spec is None or spec in TEAM_NAMES:
            continue
        checkpoint_folder = Path(spec).parent.name == "checkpoints" and Path(spec).name.startswith("step_")
        if Path(spec).suffix not in (".safetensors", ".onnx") and not checkpoint_folder:
            raise DocCommandError(f"{flag} {spec!r} is neither a policy name, a policy file nor a training "
                                  f"checkpoint folder (RUN/checkpoints/step_…)")


def _semantic_bag(ns: argparse.Namespace, argv: list[str]) -> None:
    """Read-only subcommands on a bag of the repository are cheap: run them."""
    if not (REPO / ns.bag).exists():
        return
    if ns.command == "info" or (ns.command == "echo" and ns.limit is not None and ns.limit <= 100):
        _run_script(TOOLS["dynenv-bag"], argv)


SEMANTIC: dict[str, Callable[..., None]] = {
    "dynenv-run": _semantic_run, "dynenv-train": _semantic_train, "dynenv-bench": _semantic_bench,
    "dynenv-eval": _semantic_eval,
}


def check_tool(prog: str, args: list[str], inline: bool) -> str:
    target = TOOLS[prog]
    function = _load(target)
    outcome = parse_only(lambda: function(list(args)))
    if outcome.namespace is None:
        if outcome.exit_code == 0:   # --help: run it for real too
            _run_script(target, args)
            return "help printed"
        if _accept_mention(outcome, args, inline):
            return "mention: the names exist"
        raise DocCommandError(f"{prog} refuses the arguments (exit {outcome.exit_code}): {outcome.message}")
    if prog == "dynenv-bag":
        _semantic_bag(outcome.namespace, args)
    elif prog in SEMANTIC:
        SEMANTIC[prog](outcome.namespace)
    return "parsed"


# ---------------------------------------------------------------------------------------------------- nodes
@dataclass
class DeclaredParameters:
    node_name: str
    parameters: dict[str, tuple[Any, Any]]   # name -> (default, descriptor)


def _node_class(entry: str) -> type:
    from rclpy.node import Node
    module_name, _, function = entry.partition(":")
    module = importlib.import_module(module_name)
    source = inspect.getsource(getattr(module, function))
    classes = [c for c in vars(module).values() if isinstance(c, type) and issubclass(c, Node)
               and c.__module__ == module.__name__ and re.search(rf"\b{c.__name__}\b", source)]
    assert len(classes) == 1, f"{entry}: cannot tell which Node class it runs ({classes})"
    return classes[0]


@functools.lru_cache(maxsize=None)
def declared_parameters(node: str) -> DeclaredParameters:
    """The node's parameter declarations, collected as `NODE --help` does (node_runner's stand-in Node)."""
    from dynenv_ros.ros.node_runner import collect_declarations
    declarations = collect_declarations(_node_class(NODES[node]))
    return DeclaredParameters(declarations.node_name or node, {name: (default, descriptor) for name, default,
                                                               descriptor in declarations.parameters})


def _check_value(node: str, declared: DeclaredParameters, name: str, value: Any) -> None:
    from rcl_interfaces.msg import ParameterType
    if name == "use_sim_time":   # declared by every rclpy Node
        if not isinstance(value, bool):
            raise DocCommandError(f"{node}: use_sim_time must be a bool, got {value!r}")
        return
    if name not in declared.parameters:
        raise DocCommandError(f"{node} declares no parameter {name!r} (it declares: "
                              f"{', '.join(sorted(declared.parameters))})")
    default, descriptor = declared.parameters[name]
    kind = type(default)
    if default is None and descriptor is not None:
        kind = {ParameterType.PARAMETER_BOOL: bool, ParameterType.PARAMETER_INTEGER: int,
                ParameterType.PARAMETER_DOUBLE: float, ParameterType.PARAMETER_STRING: str,
                ParameterType.PARAMETER_STRING_ARRAY: list}.get(descriptor.type, type(None))
    fits = {bool: lambda v: isinstance(v, bool),
            int: lambda v: isinstance(v, int) and not isinstance(v, bool),
            float: lambda v: isinstance(v, (int, float)) and not isinstance(v, bool),
            str: lambda v: isinstance(v, str),
            list: lambda v: isinstance(v, list)}.get(kind, lambda v: True)
    if not fits(value):
        raise DocCommandError(f"{node}: parameter {name} is {kind.__name__}, got {value!r}")
    if descriptor is None:
        return
    for bounds in list(descriptor.integer_range) + list(descriptor.floating_point_range):
        if not bounds.from_value <= value <= bounds.to_value:
            raise DocCommandError(f"{node}: parameter {name}={value!r} outside {bounds.from_value}..{bounds.to_value}")
    constraints = descriptor.additional_constraints or ""
    if constraints.startswith("one of: "):
        choices = constraints[len("one of: "):].split(", ")
        if value not in choices:
            raise DocCommandError(f"{node}: parameter {name}={value!r} is not {constraints}")


def _override_value(text: str) -> Any:
    """`-p name:=VALUE` is read as YAML by rcl (an empty value is an empty string)."""
    if text == "":
        return ""
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError:
        return text


def _params_file(path: str, node_name: str) -> dict[str, Any]:
    file = REPO / path
    if not file.is_file():
        raise DocCommandError(f"--params-file {path}: no such file in the repository")
    raw = yaml.safe_load(file.read_text()) or {}
    values: dict[str, Any] = {}
    for key, section in raw.items():
        if key.strip("/").split("/")[-1] not in ("**", "*", node_name):
            continue
        def flatten(prefix: str, mapping: dict) -> None:
            for name, value in mapping.items():
                if isinstance(value, dict):
                    flatten(f"{prefix}{name}.", value)
                else:
                    values[f"{prefix}{name}"] = value
        flatten("", (section or {}).get("ros__parameters", {}))
    return values


def check_node(node: str, args: list[str]) -> str:
    from rclpy.utilities import remove_ros_args
    if node not in NODES:
        raise DocCommandError(f"no node {node!r} in setup.py's NODES ({', '.join(NODES)})")
    own = args[:args.index("--ros-args")] if "--ros-args" in args else list(args)
    if own and own not in (["-h"], ["--help"]):
        raise DocCommandError(f"{node} takes no arguments of its own before --ros-args, got {own}")
    try:
        left = remove_ros_args([node, *args])
    except Exception as error:
        raise DocCommandError(f"rcl refuses the ROS arguments: {type(error).__name__}: {error}") from None
    if left[1:] not in ([], ["-h"], ["--help"]):
        raise DocCommandError(f"arguments outside --ros-args: {left[1:]}")
    declared = declared_parameters(node)
    checked = 0
    i, in_ros = 0, False
    while i < len(args):
        arg = args[i]
        if arg == "--ros-args":
            in_ros = True
        elif arg == "--":
            in_ros = False
        elif in_ros and arg in ("-p", "--param"):
            name, _, value = args[i + 1].partition(":=")
            _check_value(node, declared, name, _override_value(value))
            checked += 1
            i += 1
        elif in_ros and arg == "--params-file":
            for name, value in _params_file(args[i + 1], declared.node_name).items():
                _check_value(node, declared, name, value)
                checked += 1
            i += 1
        i += 1
    return f"node {node}: {checked} parameter(s) checked"


def check_service_call(args: list[str]) -> str:
    if len(args) < 2:
        raise DocCommandError("ros2 service call needs a service name and type")
    name, type_name = args[0], args[1]
    package, kind, message = (type_name.split("/") + ["", ""])[:3]
    if kind != "srv":
        raise DocCommandError(f"{type_name} is not a service type")
    try:
        service = getattr(importlib.import_module(f"{package}.srv"), message)
    except (ImportError, AttributeError) as error:
        raise DocCommandError(f"service type {type_name} does not import: {error}") from None
    if len(args) > 2:
        values = yaml.safe_load(args[2]) or {}
        request = service.Request()
        for key, value in values.items():
            if key not in service.Request.get_fields_and_field_types():
                raise DocCommandError(f"{type_name} has no request field {key!r}")
            try:
                setattr(request, key, value)
            except (AssertionError, TypeError, ValueError) as error:
                raise DocCommandError(f"{type_name}.{key} = {value!r}: {error}") from None
    parts = name.strip("/").split("/")
    node = next((p for p in parts[:-1] if p in NODES), None)
    if node is None:
        raise DocCommandError(f"service {name}: no node of setup.py's NODES in its name")
    source = Path(importlib.util.find_spec(NODES[node].partition(":")[0]).origin).read_text()
    if not re.search(rf"""["'](~/)?{re.escape(parts[-1])}["']""", source):
        raise DocCommandError(f"node {node} creates no service {parts[-1]!r}")
    return "service type, request fields and server checked"


# ------------------------------------------------------------------------------------- python, pytest, make
@functools.lru_cache(maxsize=None)
def _collect(args: tuple[str, ...]) -> tuple[int, str]:
    result = _run([sys.executable, "-m", "pytest", "--collect-only", "-q", "-p", "no:cacheprovider", *args],
                  timeout=120)
    return result.returncode, (result.stdout + result.stderr).strip()


def check_pytest(args: list[str]) -> str:
    kept: list[str] = []
    i = 0
    while i < len(args):   # -n N (xdist workers) does not change what is selected
        if args[i] in ("-n", "--numprocesses"):
            i += 2
            continue
        if re.fullmatch(r"-n\d+|--numprocesses=.*", args[i]):
            i += 1
            continue
        kept.append(args[i])
        i += 1
    code, output = _collect(tuple(kept))
    if code != 0:
        raise DocCommandError(f"pytest {' '.join(kept)} --collect-only: exit {code}: "
                              f"{' | '.join(output.splitlines()[-3:])}")
    return f"pytest selection collects: {output.splitlines()[-1]}"


def _module_targets() -> dict[str, tuple[str, str]]:
    """python -m MODULE -> ("node"|"tool", name): the modules behind setup.py's console scripts."""
    targets: dict[str, tuple[str, str]] = {}
    for name, entry in TOOLS.items():
        module, _, function = entry.partition(":")
        if function == "main":
            targets[module.removesuffix(".__main__")] = ("tool", name)
    for name, entry in NODES.items():   # a module that is both (recorder) runs its node as __main__
        targets[entry.partition(":")[0]] = ("node", name)
    return targets


def _run_main_module(run: Callable[[], Any], args: list[str], what: str, inline: bool) -> str:
    saved = sys.argv
    sys.argv = [what, *args]
    try:
        with warnings.catch_warnings():   # runpy: "found in sys.modules ... prior to execution" is expected here
            warnings.simplefilter("ignore", RuntimeWarning)
            outcome = parse_only(run)
    finally:
        sys.argv = saved
    if outcome.namespace is None and outcome.exit_code != 0 and not _accept_mention(outcome, args, inline):
        raise DocCommandError(f"{what} refuses the arguments (exit {outcome.exit_code}): {outcome.message}")
    return "parsed"


def check_python(args: list[str], inline: bool) -> str:
    if not args:
        raise DocCommandError("python without a module or script")
    if args[0] == "-m":
        if len(args) < 2:
            raise DocCommandError("python -m without a module")
        module, rest = args[1], args[2:]
        if module == "pytest":
            return check_pytest(rest)
        try:
            spec = importlib.util.find_spec(module)
        except ModuleNotFoundError:
            spec = None
        if spec is None:
            raise DocCommandError(f"no module named {module!r}")
        target = _module_targets().get(module)
        if target and target[0] == "node":
            return check_node(target[1], rest)
        if target:
            return check_tool(target[1], rest, inline)
        main_module = f"{module}.__main__" if spec.submodule_search_locations else module
        source = Path(importlib.util.find_spec(main_module).origin).read_text()
        if "parse_args" not in source:
            raise DocCommandError(f"python -m {module}: no argument parser to check it against (add a checker)")
        return _run_main_module(lambda: runpy.run_module(module, run_name="__main__", alter_sys=True), rest,
                                module, inline)
    if args[0].startswith("-"):
        raise DocCommandError(f"python {args[0]}: not a documented form this test can check")
    script = REPO / args[0]
    if not script.is_file():
        raise DocCommandError(f"no script {args[0]} in the repository")
    if "parse_args" not in script.read_text():
        raise DocCommandError(f"{args[0]}: no argument parser to check it against (add a checker)")
    return _run_main_module(lambda: runpy.run_path(str(script), run_name="__main__"), args[1:], args[0], inline)


@functools.lru_cache(maxsize=None)
def makefile() -> tuple[dict[str, str], dict[str, list[str]]]:
    """(variables with their defaults, target -> recipe lines)."""
    variables: dict[str, str] = {}
    targets: dict[str, list[str]] = {}
    current: list[str] | None = None
    for line in (REPO / "Makefile").read_text().splitlines():
        if line.startswith("\t") and current is not None:
            current.append(line.strip().lstrip("@"))
            continue
        current = None
        assignment = re.match(r"^([A-Za-z_]\w*)\s*(\?=|:=|=)\s*(.*)$", line)
        if assignment:
            variables[assignment.group(1)] = assignment.group(3)
            continue
        rule = re.match(r"^([\w.-]+)\s*:(?!=)", line)
        if rule and not rule.group(1).startswith("."):
            current = targets.setdefault(rule.group(1), [])
    return variables, targets


def check_make(args: list[str], inline: bool) -> str:
    variables, targets = makefile()
    assigned: dict[str, str] = {}
    wanted: list[str] = []
    for arg in args:
        if "=" in arg and re.fullmatch(r"[A-Za-z_]\w*", arg.partition("=")[0]):
            name, _, value = arg.partition("=")
            if name not in variables:
                raise DocCommandError(f"the Makefile has no variable {name} (it has {', '.join(variables)})")
            assigned[name] = value
        elif arg.startswith("-"):
            raise DocCommandError(f"make {arg}: an option this test does not know")
        else:
            wanted.append(arg)
    if not wanted:
        raise DocCommandError("make without a target")
    results = []
    for target in wanted:
        if target not in targets:
            raise DocCommandError(f"the Makefile has no target {target!r} (it has {', '.join(targets)})")
        if ("make", target) in SKIPPED_EXTERNAL:
            results.append(f"{target}: skipped ({SKIPPED_EXTERNAL[('make', target)]})")
            continue
        recipe = [line for line in targets[target] if "$(VENV_PY)" in line]
        if not recipe:
            raise DocCommandError(f"make {target}: no checker for its recipe {targets[target]} (add one)")
        for line in recipe:
            values = {"VENV_PY": "python", **{k: "" for k, v in variables.items() if k not in ("VENV_PY",)},
                      **assigned}
            expanded = re.sub(r"\$\((\w+)\)", lambda m: values.get(m.group(1), ""), line)
            argv = shlex.split(expanded)
            results.append(f"{target}: {check_python(argv[1:], inline=False)}")
    return "; ".join(results)


# ---------------------------------------------------------------------------------------------- dispatching
@dataclass
class Plan:
    kind: str            # "check" or "skip"
    reason: str
    run: Callable[[], str] | None = None


def _refuse(message: str) -> str:
    raise DocCommandError(message)


def plan(argv: list[str], inline: bool) -> Plan:
    """How one simple command is checked, or why it is not (it must be listed)."""
    if not argv:
        return Plan("skip", "empty")
    text = " ".join(argv)
    if inline and text in MENTIONS:
        return Plan("skip", MENTIONS[text])
    if argv[0] in SHELL_SYNTAX or (len(argv) == 1 and re.fullmatch(r"[A-Za-z_]\w*=.*", argv[0])):
        return Plan("skip", SHELL_SYNTAX.get(argv[0], "shell variable assignment (expands the commands after it)"))
    argv = _strip_prefixes(argv)
    if not argv:
        return Plan("skip", "environment assignment only")
    for prefix, reason in SKIPPED_EXTERNAL.items():
        if tuple(argv[:len(prefix)]) == prefix:
            return Plan("skip", reason)
    program, args = argv[0], argv[1:]
    in_venv = program.startswith(".venv/bin/")
    name = program.removeprefix(".venv/bin/")
    if in_venv and not (REPO / program).exists():
        return Plan("check", "venv script", lambda: _refuse(f"{program} does not exist (the bootstrap installs it)"))
    if program == "make":
        return Plan("check", "make target", lambda: check_make(args, inline))
    if name in TOOLS:
        return Plan("check", "console script", lambda: check_tool(name, args, inline))
    if name in NODES:
        return Plan("check", "node", lambda: check_node(name, args))
    if name in ("python", "python3"):
        return Plan("check", "python", lambda: check_python(args, inline))
    if name in ("pytest", "py.test"):
        return Plan("check", "pytest", lambda: check_pytest(args))
    if program == "ros2" and args[:2] == ["run", "dynenv_ros"] and len(args) >= 3:
        return Plan("check", "ros2 run", lambda: check_node(args[2], args[3:]))
    if program == "ros2" and args[:1] == ["run"] and len(args) >= 2:
        return Plan("check", "ros2 run",
                    lambda: _refuse(f"ros2 run of package {args[1]!r}: this repository's package is dynenv_ros"))
    if program == "ros2" and args[:2] == ["service", "call"]:
        return Plan("check", "ros2 service call", lambda: check_service_call(args[2:]))
    if program == "ros2" and args[:2] == ["launch", "dynenv_ros"] and len(args) >= 3:
        return Plan("check", "ros2 launch", lambda: check_launch(args[2], args[3:]))
    return Plan("unlisted", f"no checker for {program!r} and not in SKIPPED_EXTERNAL / SHELL_SYNTAX")


def check_launch(filename: str, args: list[str]) -> str:
    """`ros2 launch dynenv_ros FILE NAME:=VALUE …` (no `launch` here): the file is one of launch/, every argument
    is one it declares, and the main job accepts the settings they make (test/test_launch_file.py runs the file
    itself with stand-ins for launch)."""
    path = REPO / "launch" / filename
    if not path.is_file():
        raise DocCommandError(f"launch file {filename} is not in launch/ ({sorted(p.name for p in (REPO / 'launch').glob('*.py'))})")
    source = path.read_text()
    common = ast.literal_eval(re.search(r"^COMMON = (\{.*?\})$", source, re.M).group(1))
    declared = {*common, *re.findall(r'DeclareLaunchArgument\("(\w+)"', source)}
    overrides: dict[str, Any] = {}
    for arg in args:
        name, sep, value = arg.partition(":=")
        if not sep or name not in declared:
            raise DocCommandError(f"{arg}: not a NAME:=VALUE of a declared argument ({sorted(declared)})")
        if name == "set":
            overrides.update({k: yaml.safe_load(v) for k, _, v in (p.partition("=") for p in value.split())})
        elif name in common:
            overrides[name] = yaml.safe_load(value)
    from dynenv_ros.main_job import ConfigError, default_config_path, load_config
    try:
        load_config(default_config_path(), overrides)
    except ConfigError as error:
        raise DocCommandError(f"the main job refuses {overrides}: {error}") from None
    return f"launch file {filename} with {overrides or 'its defaults'}"


def check_command(command: DocCommand) -> list[str]:
    """Check every expansion of a documented command; returns what was done, raises DocCommandError."""
    done = []
    for argv in command.argvs:
        step = plan(argv, command.inline)
        if step.kind == "unlisted":
            raise DocCommandError(step.reason)
        if step.kind == "skip":
            done.append(f"skipped: {step.reason}")
            continue
        try:
            done.append(step.run())
        except DocCommandError as error:
            raise DocCommandError(f"{' '.join(argv)}: {error}") from None
    return done


# ------------------------------------------------------------------------------------------------------ tests
DOC_COMMANDS = all_doc_commands()


def test_the_docs_show_commands() -> None:
    where = {c.where.split(":")[0] for c in DOC_COMMANDS}
    assert "README.md" in where and len(DOC_COMMANDS) > 20, DOC_COMMANDS
    assert any(c.text.startswith("make run") for c in DOC_COMMANDS)


def test_every_doc_command_is_checked_or_listed() -> None:
    unlisted = [f"{c.where}: {' '.join(argv)}" for c in DOC_COMMANDS for argv in c.argvs
                if plan(argv, c.inline).kind == "unlisted"]
    assert not unlisted, ("documented commands with no checker: add one to test/test_doc_commands.py or list them "
                          "in SKIPPED_EXTERNAL / SHELL_SYNTAX / MENTIONS with the reason:\n" + "\n".join(unlisted))


# Commands that are only external tools, shell syntax or mentions are accounted for by the test above (each listed
# with its reason); every other one is a test case of its own.
CHECKED_COMMANDS = [c for c in DOC_COMMANDS if any(plan(argv, c.inline).kind != "skip" for argv in c.argvs)]


@pytest.mark.parametrize("command", CHECKED_COMMANDS, ids=[c.where for c in CHECKED_COMMANDS])
def test_doc_command_works_as_written(command: DocCommand) -> None:
    try:
        check_command(command)
        problem = ""
    except DocCommandError as error:
        problem = str(error)
    if problem:
        pytest.fail(f"{command.where}: `{command.text}` does not work as written: {problem}", pytrace=False)


# --- the extraction and the checkers are real: each refuses a made-up wrong command --------------------------------
def test_extraction_reads_blocks_loops_continuations_comments_and_inline_spans(tmp_path: Path) -> None:
    path = tmp_path / "doc.md"
    path.write_text(
        "Intro `dynenv-bag info|echo` and `dynenv_ros` and `ros2 run dynenv_ros\nsim_node` here.\n\n"
        "```bash\n"
        "# a comment\n"
        "dynenv-eval random --opponent random \\\n"
        "    --seeds 0 1   # trailing comment\n"
        "for V in a b; do\n"
        "  X=\"\"; [ $V = b ] && X=\"--set k=v\"\n"
        "  dynenv-train --config $V $X --run-dir runs/${V}_s$((1 % 2))\n"
        "done\n"
        "```\n"
        "```python\nimport os\n```\n")
    commands = extract(path, "doc.md")
    by_line = {c.where.split(":", 1)[1]: c for c in commands}
    assert by_line["1"].argvs == [["dynenv-bag", "info"], ["dynenv-bag", "echo"]]
    assert by_line["1#2"].argvs == [["ros2", "run", "dynenv_ros", "sim_node"]]
    assert by_line["6"].argvs == [["dynenv-eval", "random", "--opponent", "random", "--seeds", "0", "1"]]
    assert by_line["10"].argvs == [["dynenv-train", "--config", "a", "--run-dir", "runs/a_s1"],
                                   ["dynenv-train", "--config", "b", "--set", "k=v", "--run-dir", "runs/b_s1"]]
    assert set(by_line) == {"1", "1#2", "6", "9", "10"}
    assert all(plan(argv, c.inline).kind != "unlisted" for c in commands for argv in c.argvs)


@pytest.mark.parametrize("text", [
    "dynenv-train --config quick --no-such-option",                 # unknown option
    "dynenv-train --config quick --set no_such_key=1",              # unknown config key
    "dynenv-eval random --perception bogus",                         # invalid choice
    "dynenv-bag nosuchcommand bags/sample_2v2_realistic_30s",       # unknown subcommand
    "dynenv-bag info bags/sample_2v2_realistic_30s --limit 3",      # option of another subcommand
    "dynenv-run --set no_such_key=1",                                # unknown setting
    "dynenv-run --set samples_per_type=7",                           # a setting the soccer graph does not use
    "dynenv-bench sim --observation bogus",                          # invalid choice
    "dynenv-bench train --config quick --set no_such_key=1",         # unknown training key
])
def test_console_script_checker_refuses_wrong_commands(text: str) -> None:
    argv = shlex.split(text)
    with pytest.raises(DocCommandError):
        check_tool(argv[0], argv[1:], inline=False)


def test_console_script_checker_accepts_and_runs_right_commands() -> None:
    assert check_tool("dynenv-eval", ["random", "--opponent", "scripted", "--seeds", "0", "1"], False) == "parsed"
    check_tool("dynenv-bag", ["echo", "bags/sample_2v2_realistic_30s", "--topic", "/clock", "--limit", "2"], False)
    with pytest.raises(DocCommandError, match="exit status 2"):   # the run happens: a missing topic fails it
        check_tool("dynenv-bag", ["echo", "bags/sample_2v2_realistic_30s", "--topic", "/nothing", "--limit", "2"],
                   False)


@pytest.mark.parametrize("text", [
    "ros2 run dynenv_ros sim_node --ros-args -p no_such_param:=1",  # undeclared parameter
    "ros2 run dynenv_ros sim_node --ros-args -p mode:=bogus",       # not one of the choices
    "ros2 run dynenv_ros sim_node --ros-args -p players_per_team:=9",   # out of range
    "ros2 run dynenv_ros sim_node --ros-args -p players_per_team:=two",  # wrong type
    "ros2 run dynenv_ros sim_node --ros-args --bogus-ros-flag",     # rcl refuses
    "ros2 run dynenv_ros sim_node --ros-args --params-file config/no_such_file.yaml",
    "ros2 run dynenv_ros no_such_node",
    "ros2 run dynenv_ros sim_node --players 2",                     # node arguments outside --ros-args
    "ros2 service call /policy_node/load_policy dynenv_msgs/srv/LoadPolicy '{no_such_field: 1}'",
    "ros2 service call /policy_node/no_such_service dynenv_msgs/srv/LoadPolicy",
    ".venv/bin/python -m no_such_module",
    ".venv/bin/python -m benchmarks.agent --no-such-option",
    ".venv/bin/python tools/perception_figures.py --no-such-option",
    "make no_such_target",
    "make run ARG=--json",                                         # not a Makefile variable
    'make run ARGS="--set no_such_key=1"',
    'make bench ARGS="no_such_suite"',
    'make test PYTEST_ARGS="--no-such-pytest-option"',
])
def test_checkers_refuse_wrong_commands(text: str) -> None:
    step = plan(shlex.split(text), inline=False)
    assert step.kind == "check", step
    with pytest.raises(DocCommandError):
        step.run()


def test_checkers_accept_right_node_commands() -> None:
    assert "2 parameter" in check_node("scripted_policy", ["--ros-args", "-p", "robot:=team_b_1",
                                                           "-p", "policy:=random"])
    check_node("bag_player", ["--ros-args", "-p", "rate:=2"])   # an integer is taken for a double parameter


def test_an_unlisted_external_command_is_not_silently_accepted() -> None:
    assert plan(["ros2", "launch", "other_pkg", "game.launch.py"], inline=False).kind == "unlisted"
    with pytest.raises(DocCommandError, match="launch file game.launch.py is not in launch/"):
        plan(["ros2", "launch", "dynenv_ros", "game.launch.py"], inline=False).run()
    with pytest.raises(DocCommandError, match="not a NAME:=VALUE of a declared argument"):
        plan(["ros2", "launch", "dynenv_ros", "dynenv.launch.py", "player_per_team:=2"], inline=False).run()
    assert plan(["docker", "run", "x"], inline=True).kind == "unlisted"
    assert plan(["ros2", "bag", "info", "x"], inline=False).kind == "skip"


if __name__ == "__main__":   # list the documented commands and how each is checked
    for doc_command in DOC_COMMANDS:
        kinds = sorted({plan(argv, doc_command.inline).kind + ": " + plan(argv, doc_command.inline).reason
                        for argv in doc_command.argvs})
        print(f"{doc_command.where}\t{doc_command.text}\t{'; '.join(kinds)}")
