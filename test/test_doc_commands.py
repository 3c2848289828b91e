"""Every command shown in README.md and docs/*.md runs as written, in a scratch directory, shortened where it is long.

What counts as a command:
- each command line of a fenced ``bash`` / ``sh`` / ``shell`` / ``console`` block (comments dropped, ``\\``
  continuations joined, ``for`` loops and ``VAR=...`` assignments of the block expanded: the loop body runs for
  every value), and a trailing ``# venv: COMMAND`` comment, the venv equivalent of a full-ROS command on its line
  (it runs like any other command);
- each inline code span that starts with an entry point (``make``, ``.venv/bin/…``, ``dynenv-…``, ``ros2 …``,
  ``python …``, ``pytest …``, optionally behind ``time`` / ``taskset -c N`` / ``VAR=value``); spans may run over a
  line break, ``\\|`` in tables is ``|``, and in inline spans ``a|b|c`` lists alternatives (each one is a command).
Placeholders (``<robot>``, ``DIR``, ``RUN``, ``…``) are replaced by the real values listed in PLACEHOLDERS.

What happens to each (``DocRunner.do``), in this order:
1. skipped, with the reason listed: an external tool CI does not have (SKIPPED_EXTERNAL: ``source``, colcon,
   network ``git`` / ``pip``, ``ros2 bag`` / ``ros2 security``), shell syntax (SHELL_SYNTAX) or a prose mention
   (MENTIONS). ``test_every_doc_command_is_run_or_listed`` fails for a command that is none of these and that no
   checker takes.
2. parsed, without running it (``plan``): a console script's argparse parser accepts the arguments (plus what the
   tool checks first: the ``--set`` settings of dynenv-run / dynenv-train, the policy names of dynenv-eval), a
   node's ``-p`` / ``--params-file`` parameters are ones it declares with the declared type and range, ``make T
   VAR=…`` names a target and variables of the Makefile, a service call's type and request fields exist and the
   node creates the service, a launch file declares the arguments. An inline span that only names a program or
   node without arguments (``dynenv-train``, ``ros2 run dynenv_ros policy_node``, ``make run``), or a subcommand
   or an option without the rest of a command line (``dynenv-bag reindex``, ``dynenv-bench sim --noise``) is a
   mention: the names exist, nothing runs (the blocks run these programs with arguments).
3. as written: a block's program must be what a fresh shell finds (``.venv/bin/NAME``, ``make``, a listed tool);
   a bare ``dynenv-eval`` or ``python`` in a block fails (``.venv/bin`` is not on PATH). Inline spans are prose.
4. parsed only, with the reason listed in PARSE_ONLY: a full-ROS ``ros2 launch`` / ``ros2 service call`` (no
   ``launch`` and no ros2cli in the PyPI wheels; the venv equivalent beside each runs: ``make run`` here, the
   service calls in ``test_the_docs_venv_service_calls_reach_the_node``), the test suite itself (``make test``,
   the docs' ``pytest`` selections: collected, since the suite runs those tests), a GPU, a Ray cluster or the
   sros2 keystore, and the commands measured too long for CI even shortened (each with its figure).
5. run, for real. Decisions:
   - Where: one test per doc file runs that doc's block commands in document order, then its inline spans, in
     one scratch view of the repository (``make_scratch``: entries symlinked, .git too for tools that read the
     history, SCRATCH_COPIED copied because commands write there, a fresh ``runs/`` and ``$HOME``), so a command
     uses what an earlier one of its doc made (README: train, then evaluate ``runs/quick``) and nothing lands in
     the repository. An inline span gets its own ``runs/`` in which the blocks' outputs are linked (prose may name
     them; two examples may write the same default folder). Inputs the docs assume the reader has: ``RUN`` is a
     tiny ``dynenv-train --config quick`` run made once per worker (FIXTURE_RUN); ``agent.onnx`` / ``new.onnx`` /
     ``drive.onnx`` are copies of the shipped policies (FIXTURE_FILES). ``$HOME`` is the scratch's (``~/.config/…`` keys and secrets), except
     PyTensor's compile cache (CACHES).
   - As the reader runs it: ``ros2 run dynenv_ros NODE ARGS`` runs as its venv equivalent ``.venv/bin/NODE ARGS``;
     ``VAR=value`` prefixes set the environment; wrappers (``time``, ``taskset``, ``nice``) are dropped: they change
     where and how fast, not what.
   - Shortened: SHORTER lists, per program, the options set to make it short (one training update of two worlds,
     one 2-s evaluation episode, 100 BEST draws, each benchmark suite's smallest run in BENCH_SHORT, a 2-s ``make
     run`` game, …); ``--set`` overrides are appended, so they win over the documented ones.
   - Deduplicated (``dedup_key``): a command identical after shortening to one run earlier in its doc is not run
     again (``make run`` / ``make bench ARGS=X`` count as the ``dynenv-run`` / ``dynenv-bench`` X of their
     recipe); across docs likewise, unless it names a path under ``runs/`` or ``~`` (a later command of its doc
     may read it). The expensive kinds in SAME_SHAPE run once per shape: trainings that differ only in seeds,
     paths and budget settings (a later one's ``--run-dir`` becomes a copy of the first one's, so the documented
     evaluations and merges of every seed still run), BEST comparisons of other files or metrics, games of the same
     graph and scenario, nodes started again with other remappings, and the benchmark suites of BENCH_ONCE; a
     command of a shape already run must find its inputs, and one whose output a later command of its doc reads
     (``read_later``: ``--output-dir runs/drive``, then ``dynenv-bag render runs/drive/bag``) runs itself.
   - How: programs whose work is in-process (IN_PROCESS: dynenv-train, -eval, -pretrain, -play, -bag, -keys, the
     benchmark suites that start no ROS graph) are called as ``main(argv)`` in the pytest worker, with cwd,
     ``$HOME``, environment, signal handlers, CPU affinity, torch threads and logging handlers restored
     afterwards: a subprocess pays Python + torch start-up (2-3 s, 8 s with torch._dynamo) per command, which the
     budget cannot. Whatever starts ROS or other processes (``make``, dynenv-run, dynenv-record, the ROS benchmark
     suites, nodes, ``python tools/…``) runs as a subprocess in its own process group, killed on its timeout.
   - Nodes run until stopped: the node starts, must appear on the ROS graph (a new /rosout publisher in the
     worker's ROS_DOMAIN_ID, or the one the command sets) within NODE_ALIVE_S, gets NODE_SETTLE_S more, then
     SIGINT, and must exit 0 within NODE_STOP_S.
   - Timeouts: TIMEOUT_S per command (in-process: SIGALRM), LONG_TIMEOUT_S for the kinds listed there.
   Each doc's test prints every command with what happened to it and its seconds (``-rP``);
   ``python test/test_doc_commands.py`` lists every command with its plan. Cost, measured on the 2-core development
   machine (load about 2): the file takes 3.5 min with ``-n 2`` (395 s of worker time; the parse-only version it
   replaced: 47 s, 85 s), so it adds about 2.5 min to ``make test``; DOC_TEST_ORDER balances the two workers.
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
import json
import os
import re
import runpy
import shlex
import shutil
import signal
import subprocess
import sys
import time
import traceback
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

# Commands CI cannot run, by their first words, and why. A documented command that is neither run nor listed
# (here or in PARSE_ONLY) fails test_every_doc_command_is_run_or_listed.
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
# Shell tools a documented block uses, run as they are (in the scratch view).
SHELL_TOOLS: dict[str, str] = {"mkdir": "creates the folder later commands write into",
                               "zgrep": "reads the lines of a committed, gzip-compressed training log"}
# Inline spans that are prose, not commands (exact text) and why.
MENTIONS: dict[str, str] = {
    "pytest": "the dependency's name in the README's dependency table",
    "ros2 run": "the verb in prose ('Users `ros2 run` the simulator …', 'where `ros2 run` looks'), no node named",
    "ros2 run dynenv_ros": "the command's prefix in prose (docs/ros_graph.md: each node of it is a venv script)",
    "python3 -c while True: pass": "an endless CPU burner, named as the load a measurement ran under",
    "dynenv-keys generate": "names the command in prose (the folder it writes to, what makes the key); its runnable "
                            "forms are `.venv/bin/dynenv-keys generate …`",
}
# Placeholder -> the real value substituted to check the command ("a|b" checks both).
PLACEHOLDERS: dict[str, str] = {
    "<robot>": "team_a_0",
    "<suite>": "msgs|setup|sim|vector|ros|policy|train|soak",   # every suite of dynenv-bench
    "DIR": "runs/doc_commands/recording",   # dynenv-record --output DIR
    "S": "5",                               # dynenv-record --duration S
    "N": "2",                               # --players-per-team N
    "O": "partial|padded",                  # --observation O
    "RUN": "runs/doc_fixture/quick",        # RUN/policy.safetensors: a dynenv-train run directory (FIXTURE_RUN)
    "RUN_DIR": "runs/doc_fixture/quick",
    "bag:=…": "bag:=bags/sample_2v2_realistic_30s",   # bag_player -p bag:=…
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
    venv_comment: bool = False       # a `# venv: COMMAND` comment: the venv equivalent of the command on its line

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
    out = [commands[n] for n in sorted(commands)]
    for line in lines:   # `ros2 launch … # venv: make run ARGS=…`: the equivalent is a command of its own
        venv = re.search(r"#\s*venv:\s*(.+)$", line.text)
        if venv:
            text = venv.group(1).strip()
            out.append(DocCommand(where(line.number), text, inline=False, argvs=[_words(text)], venv_comment=True))
    return out


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


def _semantic_keys(namespace: argparse.Namespace) -> None:
    """`dynenv-keys call|sign-request SERVICE TYPE VALUES`: the service type, its request fields and the node's
    service exist, as for `ros2 service call`."""
    if namespace.command in ("call", "sign-request"):
        check_service_call([namespace.service, namespace.type, namespace.values])


SEMANTIC: dict[str, Callable[..., None]] = {
    "dynenv-run": _semantic_run, "dynenv-train": _semantic_train, "dynenv-bench": _semantic_bench,
    "dynenv-eval": _semantic_eval, "dynenv-keys": _semantic_keys,
}


def check_tool(prog: str, args: list[str], inline: bool) -> str:
    target = TOOLS[prog]
    function = _load(target)
    outcome = parse_only(lambda: function(list(args)))
    if outcome.namespace is None:
        if outcome.exit_code == 0:   # --help (it runs for real afterwards)
            return "parsed"
        if _accept_mention(outcome, args, inline):
            return MENTIONED
        raise DocCommandError(f"{prog} refuses the arguments (exit {outcome.exit_code}): {outcome.message}")
    if prog in SEMANTIC:
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
    from dynenv_ros.graph.inventory_table import CLASSES
    if node in CLASSES:         # the services it offers (test_inventory checks the table against the started node)
        offered = f"~/{parts[-1]}" in CLASSES[node]["services"] or name in CLASSES[node]["services"]
    else:                       # a node outside the inventory: its module must name the service
        source = Path(importlib.util.find_spec(NODES[node].partition(":")[0]).origin).read_text()
        offered = re.search(rf"""["'](~/)?{re.escape(parts[-1])}["']""", source) is not None
    if not offered:
        raise DocCommandError(f"node {node} creates no service {parts[-1]!r}")
    return "service type, request fields and server checked"


# ------------------------------------------------------------------------------------- python, pytest, make
@functools.lru_cache(maxsize=None)
def _collect(args: tuple[str, ...]) -> tuple[int, str]:
    result = subprocess.run([sys.executable, "-m", "pytest", "--collect-only", "-q", "-p", "no:cacheprovider", *args],
                            cwd=REPO, capture_output=True, text=True, timeout=240)
    return result.returncode, (result.stdout + result.stderr).strip()


def _file_selection(args: list[str]) -> list[str] | None:
    """The test files of a selection that is only files (and -q), else None."""
    files = [a for a in args if a not in ("-q", "-v")]
    return files if files and all(re.fullmatch(r"test/test_\w+\.py", f) for f in files) else None


@functools.lru_cache(maxsize=None)
def _collected_files() -> dict[str, int]:
    """Test file -> tests collected, for every file the docs' pytest commands name: one collection for all of
    them (a collection imports the files' modules; one each cost 10 s)."""
    files = sorted({f for c in DOC_COMMANDS for argv in c.argvs for f in (_file_selection(_pytest_args(argv)) or [])})
    code, output = _collect(tuple(files))
    if code != 0:
        raise DocCommandError(f"pytest --collect-only {' '.join(files)}: exit {code}: "
                              f"{' | '.join(output.splitlines()[-3:])}")
    counts: dict[str, int] = {}
    for line in output.splitlines():
        if "::" in line:
            counts[line.split("::")[0]] = counts.get(line.split("::")[0], 0) + 1
    return counts


def _pytest_args(argv: list[str]) -> list[str]:
    """The pytest arguments of `pytest …` / `python -m pytest …` (else nothing)."""
    argv = _strip_prefixes(argv)
    name = argv[0].removeprefix(".venv/bin/") if argv else ""
    if name in ("pytest", "py.test"):
        return argv[1:]
    if name in ("python", "python3") and argv[1:3] == ["-m", "pytest"]:
        return argv[3:]
    return []


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
    if kept == ["test"] or not kept:
        return "the whole suite (this test is part of it)"
    files = _file_selection(kept)
    if files is not None:
        counts = _collected_files()
        empty = [f for f in files if not counts.get(f)]
        if empty:
            raise DocCommandError(f"pytest {' '.join(kept)}: no test collected from {', '.join(empty)}")
        return f"pytest selection collects {sum(counts[f] for f in files)} tests"
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
    if outcome.namespace is None and outcome.exit_code != 0:
        if _accept_mention(outcome, args, inline):
            return MENTIONED
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
    if args[0] == "tools/ros2_service_call.py":   # the venv's `ros2 service call`: checked as that
        _run_main_module(lambda: runpy.run_path(str(script), run_name="__main__"), args[1:], args[0], inline)
        return check_service_call(args[1:])
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


def check_zgrep(args: list[str]) -> str:
    """A documented zgrep reads a committed log: the file is there and the pattern finds its lines."""
    done = subprocess.run(["zgrep", "-c", *args], cwd=REPO, capture_output=True, text=True, timeout=60)
    if done.returncode != 0:
        _refuse(f"zgrep {' '.join(args)}: exit status {done.returncode} (no matching line, or no such file) "
                f"{done.stderr.strip()}")
    return f"zgrep: {done.stdout.strip()} matching lines"


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
MENTIONED = "mention: the names exist"


@dataclass
class Plan:
    kind: str            # "check" (parsed, then run or listed parse-only), "skip" or "unlisted"
    reason: str
    run: Callable[[], str] | None = None


def _refuse(message: str) -> str:
    raise DocCommandError(message)


def plan(argv: list[str], inline: bool) -> Plan:
    """How one simple command is checked before it runs, or why it is not (it must be listed)."""
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
    if program == "zgrep" and not inline:
        return Plan("check", SHELL_TOOLS[program], lambda: check_zgrep(args))
    if program in SHELL_TOOLS and not inline:
        return Plan("check", SHELL_TOOLS[program], lambda: "shell tool")
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
    table = re.search(r"^(COMMON|ARGUMENTS) = (\{.*?\})$", source, re.M | re.S)
    if table is None:
        raise DocCommandError(f"launch file {filename}: no COMMON (main-job settings) or ARGUMENTS table")
    if table.group(1) == "ARGUMENTS":       # a node's launch file (ros_sports_policy): its own arguments only
        declared = set(ast.literal_eval(table.group(2)))
        unknown = [a for a in args if a.partition(":=")[0] not in declared or ":=" not in a]
        if unknown:
            raise DocCommandError(f"{unknown}: not NAME:=VALUE of a declared argument ({sorted(declared)})")
        return f"launch file {filename} with {args or 'its defaults'}"
    common = ast.literal_eval(table.group(2))
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


# ------------------------------------------------------------------------------------------ running for real
# Commands that are parsed (above) but not run, and why. Matched (re.search) against the command as shown, with its
# wrappers and VAR=value prefixes dropped and `.venv/bin/` removed.
PARSE_ONLY: list[tuple[str, str]] = [
    (r"^ros2 launch ", "no `launch` in the PyPI wheels; test/test_launch_file.py runs the file with stand-ins, and "
                       "its venv equivalent (`# venv: make run ARGS=…` beside it) runs here"),
    (r"^ros2 service call ", "no ros2cli in the PyPI wheels; its venv equivalent beside it "
                             "(tools/ros2_service_call.py) runs against a started node in "
                             "test_the_docs_venv_service_calls_reach_the_node"),
    (r"^python tools/ros2_service_call\.py ", "calls a node started by an earlier command: "
                                             "test_the_docs_venv_service_calls_reach_the_node runs it against one"),
    (r"^dynenv-keys call ", "a signed service call of a node started by an earlier command: "
                            "test_the_docs_venv_service_calls_reach_the_node runs each against the node deploy.md "
                            "starts with the operator's key"),
    (r"^\w+ --ros-args --enclave ", "needs the sros2 keystore of `ros2 security` (not in the wheels; "
                                     "docs/ros_graph.md says this set-up is not tested)"),
    (r"^make test( |$)", "the test suite this test belongs to (running it here would recurse); its recipe and "
                         "PYTEST_ARGS selection are checked"),
    (r"^make test-fast( |$)", "the quick part of the suite this test belongs to (running it here would recurse); its "
                              "recipe and marker selection are collected"),
    (r"^make lint( |$)", "runs before the suite in `make test`, which this test belongs to; its recipe is checked"),
    (r"^(python -m )?pytest ", "tests of this suite (the suite runs them); the selection is collected"),
    (r"(--device[ =]|device=)cuda", "needs a CUDA GPU"),
    (r"ray_address=HEAD|--address HEAD", "joins the user's Ray cluster (HEAD:6379); test/test_ray_cluster.py starts "
                                         "a real head and node with these options"),
    # measured too long for CI even shortened (the figures: this machine, 2 busy cores)
    (r"graph=train", "the training graph's exit status says whether the policy learnt in its train_updates (3-6 "
                     "minutes); shortened it cannot learn and fails by design (44 s at one update); test_main_job.py::"
                     "test_the_train_graph_runs_games_policies_and_the_trainer_and_summarises runs it for 3 updates"),
    (r"^dynenv-eval runs/issue39/\S+/kept_policies/step_",
     "a copy kept by a full-length run (kept_policies/, one per 250,000 env steps): the shortened run of the command "
     "before keeps none; test/test_kept_policies.py and test/test_learning_curriculum.py keep and load such copies, "
     "and each run's chosen copy is committed and evaluated by a command that runs"),
    (r"^dynenv-train (--config league_(sizes|anchor|light_anchor|5v5)|--resume runs/issue39/league_light_anchor_s0) ",
     "two rollout worker processes, one playing 5v5, and the learner: about 22 s each even at one update (the full "
     "suite of 29 Nov 2026 took 152 s for docs/results.md with them, 108 s without); --config league (the same "
     "runner with the league and an init policy) runs, and test/test_league.py trains with two team sizes on two "
     "workers; the --resume continues the league_light_anchor run (parse-only here, so there is nothing to resume)"),
    (r"^python tools/average_policies\.py ", "its inputs are the kept checkpoints of a league_anchor run (that "
                                          "training is parse-only, above); the averages it made are committed and "
                                          "evaluated by the commands after it; test/test_average_policies_tool.py "
                                          "averages policies and checks the mean"),
    (r"^dynenv-sweep ", "a local Ray cluster training and evaluating every variant x seed: 66 s even with one "
                        "update per run; test/test_sweep_scratch.py runs sweeps"),
    (r"^(dynenv-bench |make bench ARGS=)(ros|soak)( |$)", "starts the ROS graph 4 times (ros: 36 s at 2 sim s) / "
                                                           "needs a started graph's diagnostics (soak: > 30 s)"),
    (r"^(dynenv-bench |make bench ARGS=)weights-flood( |$)",
     "a real-time game with a learned-policy node (torch start-up) plus the flooding process: 10 s of start-up before "
     "any phase; test_weights_attacks.py::test_an_oversized_flood_costs_neither_memory_nor_a_period floods a policy "
     "node the same way (benchmarks.weights_flood.oversized_announcement) and bounds its memory"),
    (r"^(dynenv-bench |make bench ARGS=)(learner|train --config async)( |$)",
     "the async preset's learner and worker processes: 16 s each even at one update; dynenv-train --config async "
     "(README.md) runs that runner"),
    (r"^python tools/paper_comparison\.py ", "evaluates every run and runs BEST on every pair: 157 s even at one "
                                             "2-s episode and 100 draws; the evaluations and comparisons it makes "
                                             "are the commands of 'Every evaluation, as a command', which run"),
    (r"^python tools/ab_benchmark\.py ", "checks out a git worktree per commit through the repository's own .git "
                                        "(the scratch view links it: the checkouts would stay registered there) and "
                                        "needs 3cd871e in the clone's history; its smallest run (--rounds 1 --suites "
                                        "sim --sim-steps 50) took 12 s with one of its two trees already checked out "
                                        "(2 busy cores, load 5.6); --summary-only reads the runs.jsonl that run "
                                        "writes. test/test_ab_benchmark.py runs a whole A/B run over a throw-away "
                                        "repository"),
    (r"^python tools/driving_perception_statistics\.py( --maxima)?$", "no option shortens it: 41 s (all figures), "
                                                                     "over 90 s (--maxima); its --timing part runs"),
]

# Programs (by their first words, `.venv/bin/` removed) run in the pytest worker as main(argv), why in the module
# docstring; the rest run as subprocesses.
IN_PROCESS: dict[tuple[str, ...], str] = {
    ("dynenv-train",): "dynenv_ros.learning.train_cli:main",
    ("dynenv-eval",): "dynenv_ros.evaluation.cli:main",
    ("dynenv-pretrain",): "dynenv_ros.learning.pretrain:main",
    ("dynenv-play",): "dynenv_ros.envs.play:main",
    ("dynenv-bag",): "dynenv_ros.bags.inspect:main",
    ("dynenv-keys",): "dynenv_ros.ros.keys_cli:main",
    **{("dynenv-bench", suite): "benchmarks.__main__:main"
       for suite in ("sim", "vector", "policy", "train", "learner", "cores", "msgs")},
    ("python", "-m", "benchmarks", "sim"): "benchmarks.__main__:main",
    ("python", "-m", "benchmarks", "policy"): "benchmarks.__main__:main",
}
TIMEOUT_S = 90.0
LONG_TIMEOUT_S: dict[tuple[str, ...], float] = {("make", "run"): 240.0, ("dynenv-run",): 240.0}
NODE_ALIVE_S = 60.0     # a node must appear on the ROS graph within this (a loaded machine starts torch slowly)
NODE_STOP_S = 20.0      # and exit 0 within this after SIGINT
# Files the docs assume the reader has (made or exported by them): copies of the shipped policies of that kind.
FIXTURE_FILES = {"agent.onnx": "policy_node/pretrained/policy.onnx", "new.onnx": "policy_node/pretrained/policy.onnx",
                 "drive.onnx": "policy_node/pretrained/driving/policy.onnx"}
FIXTURE_RUN = "runs/doc_fixture/quick"   # what PLACEHOLDERS' RUN stands for: a dynenv-train run directory
# $HOME is the scratch's; PyTensor's compile cache (BEST's model, 40 s to compile cold) stays the user's: a cache,
# not an output.
CACHES = {"PYTENSOR_FLAGS": f"base_compiledir={Path.home() / '.pytensor'}"}
NODE_SETTLE_S = 0.5     # a node on the graph is given this long to finish starting before SIGINT


def _replace(args: list[str], option: str, values: list[str], nargs: str = "1") -> list[str]:
    """``args`` with ``option`` taking ``values`` instead of the documented ones (nargs "1": one value, "+": every
    value up to the next option), appended when the command does not give it."""
    out: list[str] = []
    found = False
    i = 0
    while i < len(args):
        if args[i] == option or args[i].startswith(option + "="):
            out += [option, *values]
            found = True
            i += 1
            if args[i - 1] == option:
                if nargs == "1":
                    i += 1
                else:
                    while i < len(args) and not args[i].startswith("--"):
                        i += 1
            continue
        out.append(args[i])
        i += 1
    return out if found else out + [option, *values]


def _first_value(args: list[str], option: str) -> str | None:
    for i, arg in enumerate(args):
        if arg == option and i + 1 < len(args):
            return args[i + 1]
        if arg.startswith(option + "="):
            return arg.partition("=")[2]
    return None


def _settings(args: list[str]) -> dict[str, str]:
    return dict(args[i + 1].partition("=")[::2] for i, a in enumerate(args[:-1]) if a == "--set")


def _is_async(args: list[str]) -> bool:
    config = _first_value(args, "--config") or ""
    return config.startswith("async") or _settings(args).get("runner") == "async"


def _short_train(args: list[str]) -> list[str]:
    if "--from-bag" in args:
        return _replace(args, "--epochs", ["1"])
    if "--resume" in args:
        return args   # one update more than the run holds: added when it runs (_resume_one_update)
    extra = ["--set", "total_env_steps=1", "--set", "num_envs=2"]
    return args + extra + (["--set", "workers=1"] if _is_async(args) else [])


def _short_eval(args: list[str]) -> list[str]:
    if args[:1] in (["merge"], ["training-best"], ["ratio"], ["mean"]):     # reads files only: fast as written
        return args
    if args[:1] == ["compare"]:   # one chain: PyMC samples it in this process (two: a process each, 15 s)
        return _replace(_replace(_replace(args, "--draws", ["100"]), "--tune", ["100"]), "--chains", ["1"])
    return _replace(_replace(args, "--episodes", ["1"]), "--episode-seconds", ["2"])


BENCH_SHORT: dict[str, list[tuple[str, list[str]]]] = {   # suite -> (option, values) set on it
    "sim": [("--steps", ["10"]), ("--repeat", ["1"])],
    "vector": [("--steps", ["4"]), ("--chunk", ["2"]), ("--repeat", ["1"])],
    "policy": [("--decisions", ["200"]), ("--warmup", ["0"]), ("--repeat", ["1"]), ("--robots", ["4"])],
    "train": [("--updates", ["1"]), ("--warmup", ["0"]), ("--repeat", ["1"]), ("--sim-steps", ["10"])],
    "learner": [("--repeat", ["1"]), ("--gemm", ["64"])],
    "cores": [("--seconds", ["0.2"]), ("--repeat", ["1"]), ("--workloads", ["interpreter"])],
    "msgs": [("--repeat", ["1"])], "setup": [("--repeat", ["1"])], "auth": [("--repeat", ["1"])],
    "ros": [("--sim-seconds", ["2"]), ("--wall-seconds", ["1"]), ("--repeat", ["1"])],
    "soak": [("--minutes", ["0.1"]), ("--warmup-s", ["2"]), ("--sample-s", ["1"])],
    "flood": [("--calm-s", ["1"]), ("--flood-s", ["1"])],
    "ros-train": [("--games", ["1"]), ("--minutes", ["0.2"])],
    "camera": [("--periods", ["8"]), ("--repeat", ["1"]), ("--profiles", ["jitter_drops_late"])],
    "live-view": [("--frames", ["20"]), ("--repeat", ["1"])],
    "localization": [("--steps", ["5"]), ("--calls", ["10"]), ("--repeat", ["1"])],
}


def _short_bench(args: list[str]) -> list[str]:
    if not args or args[0] not in BENCH_SHORT or "-h" in args or "--help" in args:
        return args
    for option, values in BENCH_SHORT[args[0]]:
        args = _replace(args, option, values, nargs="+" if option in ("--games", "--profiles", "--workloads") else "1")
    if args[0] == "sim" and _first_value(args, "--observation") == "image":   # a rendered camera image per step
        args = _replace(args, "--steps", ["2"])
    if args[0] == "policy" and "--agent" in args:
        args = _replace(args, "--iterations", ["2"])
    if args[0] == "train":
        args += ["--set", "num_envs=2"] + (["--set", "workers=1"] if _is_async(args) else [])
    return args


def _short_run(args: list[str]) -> list[str]:
    """dynenv-run / make run ARGS: a 2-s game; the training graph: one update of one game."""
    settings = {k.strip(): v for k, v in (s.partition("=")[::2] for s in
                                          (args[i + 1] for i, a in enumerate(args[:-1]) if a == "--set"))}
    if "-h" in args or "--help" in args:
        return args
    if settings.get("graph") == "train":
        return args + ["--set", "train_updates=1", "--set", "games=1", "--set", "episode_seconds=2"]
    if settings.get("graph") == "selfcheck":
        return args
    return args + ["--set", "duration_s=2"]


def _short_make(args: list[str]) -> list[str]:
    target = next((a for a in args if "=" not in a), "")
    short = {"run": _short_run, "bench": _short_bench}.get(target)
    if short is None:
        return args
    assigned = [a for a in args if a.startswith("ARGS=")]
    value = shlex.split(assigned[0].partition("=")[2]) if assigned else []
    new = f"ARGS={shlex.join(short(value))}"
    return [a for a in args if not a.startswith("ARGS=")] + [new]


@dataclass(frozen=True)
class Shorter:
    what: str                                        # the documented change
    apply: Callable[[list[str]], list[str]]          # arguments (after the program) -> shortened arguments


# Program (first words, `.venv/bin/` removed) -> how its arguments are shortened. Programs not listed run as written.
SHORTER: dict[tuple[str, ...], Shorter] = {
    ("dynenv-train",): Shorter("one update of two worlds: --set total_env_steps=1 --set num_envs=2 (async presets "
                               "also --set workers=1); --from-bag: --epochs 1; --resume: one update more than the "
                               "run holds", _short_train),
    ("dynenv-eval",): Shorter("--episodes 1 --episode-seconds 2; compare: --draws 100 --tune 100 --chains 1; "
                              "merge, training-best, ratio, mean: as written",
                              _short_eval),
    ("dynenv-bench",): Shorter("each suite's smallest run (BENCH_SHORT): e.g. sim --steps 10 --repeat 1",
                               _short_bench),
    ("python", "-m", "benchmarks"): Shorter("as dynenv-bench", _short_bench),
    ("dynenv-run",): Shorter("--set duration_s=2 (graph train: --set train_updates=1 --set games=1 "
                             "--set episode_seconds=2)", _short_run),
    ("make",): Shorter("run / bench: ARGS shortened as dynenv-run / dynenv-bench", _short_make),
    ("dynenv-play",): Shorter("--seconds 2", lambda a: _replace(a, "--seconds", ["2"])),
    ("dynenv-pretrain", "generate"): Shorter("--train 4 --test 2 --worlds-per-batch 2", lambda a: _replace(
        _replace(_replace(a, "--train", ["4"]), "--test", ["2"]), "--worlds-per-batch", ["2"])),
    ("dynenv-pretrain", "train"): Shorter("--epochs 1", lambda a: _replace(a, "--epochs", ["1"])),
    ("dynenv-sweep",): Shorter("one update of two worlds per run (as dynenv-train), the first two seeds, one 1-episode "
                               "evaluation seed; --best: --set of BEST draws is not available, so as written",
                               lambda a: _replace(_replace(_replace(
                                   a + ["--set", "total_env_steps=1", "--set", "num_envs=2", "--set", "workers=1",
                                        "--set", "episode_seconds=2"],
                                   "--seeds", (_first_value(a, "--seeds") and a[a.index("--seeds") + 1:][:2]) or ["0"],
                                   nargs="+"), "--eval-episodes", ["1"]), "--eval-seeds", ["100"], nargs="+")),
    ("dynenv-record",): Shorter("--duration 1", lambda a: _replace(a, "--duration", ["1"])),
    ("python", "-m", "benchmarks.agent"): Shorter("--envs 2 --iterations 2 --repeat 1", lambda a: _replace(_replace(
        _replace(a, "--envs", ["2"]), "--iterations", ["2"]), "--repeat", ["1"])),
    ("python", "tools/perception_statistics.py"): Shorter("--periods 5 --audit-periods 5 --layout-periods 5",
                                                          lambda a: _replace(_replace(_replace(
                                                              a, "--periods", ["5"]), "--audit-periods", ["5"]),
                                                              "--layout-periods", ["5"])),
    ("python", "tools/teacher_agreement.py"): Shorter("--periods 5 --worlds 1", lambda a: _replace(
        _replace(a, "--periods", ["5"]), "--worlds", ["1"])),
    ("python", "tools/paper_comparison.py"): Shorter("--episodes 1 --episode-seconds 2 --draws 100 --tune 100",
                                                     lambda a: _replace(_replace(_replace(_replace(
                                                         a, "--episodes", ["1"]), "--episode-seconds", ["2"]),
                                                         "--draws", ["100"]), "--tune", ["100"])),
}


def _normal(argv: list[str]) -> list[str]:
    """The command as a reader means it: wrappers and VAR=value prefixes dropped, `.venv/bin/` removed, python3 =
    python, `ros2 run dynenv_ros NODE` = NODE (its venv equivalent)."""
    argv = _strip_prefixes(argv)
    argv = [argv[0].removeprefix(".venv/bin/"), *argv[1:]] if argv else argv
    if argv and argv[0] == "python3":
        argv = ["python", *argv[1:]]
    if argv[:3] == ["ros2", "run", "dynenv_ros"] and len(argv) > 3:
        argv = argv[3:]
    return argv


def _matching(table: dict[tuple[str, ...], Any], argv: list[str]) -> tuple[tuple[str, ...], Any] | None:
    """The longest key of ``table`` that ``argv`` starts with."""
    keys = [k for k in table if tuple(argv[:len(k)]) == k]
    return (max(keys, key=len), table[max(keys, key=len)]) if keys else None


def shorten(argv: list[str]) -> list[str]:
    """The normal command with SHORTER's options."""
    argv = _normal(argv)
    match = _matching(SHORTER, argv)
    if match is None:
        return argv
    prefix, shorter = match
    head = 1 if prefix[0] != "python" else len(prefix)
    return argv[:head] + shorter.apply(argv[head:])


def dedup_key(argv: list[str]) -> tuple[str, ...]:
    """What makes two commands the same run: the environment prefix and the shortened command, `make run` /
    `make bench ARGS=X` being the `dynenv-run` / `dynenv-bench` X their recipe runs (after the bootstrap)."""
    short = shorten(argv)
    target = {"run": "dynenv-run", "bench": "dynenv-bench"}.get(short[1] if short[:1] == ["make"] and
                                                              len(short) > 1 else "")
    if target and all(a.startswith("ARGS=") for a in short[2:]):
        short = [target, *shlex.split(next((a.partition("=")[2] for a in short[2:]), ""))]
    if short[:3] == ["python", "-m", "benchmarks"]:
        short = ["dynenv-bench", *short[3:]]
    return (*[f"{k}={v}" for k, v in _env_prefix(argv).items()], *short)


def _names_only(argv: list[str]) -> bool:
    """An inline span that is only a program or node (`dynenv-train`, `ros2 run dynenv_ros policy_node`, `python -m
    policy_node.policy_node`, `make run`): prose naming it, not a command line to run (the parse checked the name)."""
    normal = _normal(argv)
    return len(normal) == 1 or (normal[:2] == ["python", "-m"] and len(normal) == 3) or \
        (normal[:1] == ["make"] and len(normal) == 2)


def parse_only_reason(argv: list[str]) -> str | None:
    text = " ".join(_normal(argv))
    return next((reason for pattern, reason in PARSE_ONLY if re.search(pattern, text)), None)


def _env_prefix(argv: list[str]) -> dict[str, str]:
    env: dict[str, str] = {}
    for word in argv:
        if not re.fullmatch(r"[A-Za-z_]\w*=.*", word):
            break
        key, _, value = word.partition("=")
        env[key] = value
    return env


def _is_path(word: str) -> bool:
    return "/" in word and not word.startswith("-") and "=" not in word.split("/")[0]


# Training settings that set its length, logging and checkpoints, not what it trains.
BUDGET_SETTINGS = ("total_env_steps", "max_minutes", "log_every_updates", "checkpoint_every_minutes",
                   "keep_checkpoints")


def _anonymous(argv: list[str]) -> tuple[str, ...] | None:
    """The shortened command with seed numbers, file paths and budget settings made anonymous."""
    words = shorten(argv)
    for option in ("--run-dir", "--seed"):   # where it writes and its seed are not what it trains
        if option in words:
            del words[words.index(option):words.index(option) + 2]
    kept = [w for i, w in enumerate(words) if w != "--no-progress" and not (
        w == "--set" and i + 1 < len(words) and words[i + 1].partition("=")[0] in BUDGET_SETTINGS) and not (
        i and words[i - 1] == "--set" and w.partition("=")[0] in BUDGET_SETTINGS)]
    out = []
    for word in kept:
        word = re.sub(r"(?<=seed=)\d+", "S", word)
        word = re.sub(r"_s\d+\b", "_sS", word)
        key, sep, value = word.partition("=")
        if _is_path(word):
            word = "PATH"
        elif sep and "/" in value:
            word = f"{key}=PATH"
        out.append(word)
    out = [("S" if i and out[i - 1] == "--seed" else w) for i, w in enumerate(out)]
    return tuple(out)


# Benchmark suites that cost 10-30 s even shortened: their first documented form runs, the others differ in its numbers
# and options (parsed). sim runs every form (0.1-1 s).
BENCH_ONCE = ("vector", "cores", "learner", "camera", "flood", "policy", "ros-train", "setup", "msgs", "auth")


def _bench(argv: list[str]) -> tuple[str, ...] | None:
    key = dedup_key(argv)
    if key[:1] != ("dynenv-bench",) or len(key) < 2 or key[1] not in (*BENCH_ONCE, "train"):
        return None
    if key[1] == "train":
        return ("bench", "train", "async" if _is_async(list(key)) else "sync")
    return ("bench", key[1], "agent" if "--agent" in key else "")


def _node(argv: list[str]) -> tuple[str, ...] | None:
    """A node started again with other remappings (`-r __ns:=/game_2`): the same node doing the same."""
    key = list(dedup_key(argv))
    if not key or key[0] not in NODES or "-h" in key or "--help" in key:
        return None
    return ("node", *[w for i, w in enumerate(key) if w != "-r" and not (i and key[i - 1] == "-r")])


def _comparison(argv: list[str]) -> tuple[str, ...] | None:
    """BEST on two files: the same code whatever the files and the metric."""
    return ("compare", *sorted(w for w in shorten(argv) if w.startswith("--")))


def _game(argv: list[str]) -> tuple[str, ...] | None:
    """A main-job game (make run / dynenv-run) by the graph and scenario it plays."""
    key = dedup_key(argv)
    args = list(key[key.index("dynenv-run") + 1:]) if "dynenv-run" in key else []
    settings = {k.strip(): v for k, v in (args[i + 1].partition("=")[::2] for i, a in enumerate(args[:-1])
                                          if a == "--set")}
    return ("main job", settings.get("graph", "soccer"), settings.get("scenario", "robocup"))


# Expensive kinds whose same-shape repetitions are the same code on other numbers: not run again. Prefix of the
# normal command -> (why, its shape: None = always runs).
SAME_SHAPE: dict[tuple[str, ...], tuple[str, Callable[[list[str]], tuple[str, ...] | None]]] = {
    ("dynenv-train",): ("a training that differs only in seed, budget (BUDGET_SETTINGS) and run directory: its run "
                        "directory is the first one's, copied", _anonymous),
    ("dynenv-eval", "compare"): ("BEST on other files or another metric (PyMC, 3-20 s each): the files must exist",
                                 _comparison),
    ("make", "run"): ("a game of the same graph and scenario with other settings (18 s each): the main job accepts "
                      "them (parsed); test/test_main_job.py plays the perceiving team, a trained team A and the "
                      "driving scenario", _game),
    ("dynenv-run",): ("as make run", _game),
    ("dynenv-bench",): ("a benchmark suite run before with other numbers (BENCH_ONCE: 10-30 s each)", _bench),
    **{(node,): ("the node started before with other remappings (2-10 s each)", _node) for node in NODES},
    ("make", "bench"): ("as dynenv-bench", _bench),
    ("python", "-m", "benchmarks"): ("as dynenv-bench", _bench),
}


def shape_key(argv: list[str]) -> tuple[str, ...] | None:
    match = _matching(SAME_SHAPE, _normal(argv))
    return None if match is None else match[1][1](argv)


# Options whose value is a file or folder the command writes.
OUTPUT_OPTIONS = ("--run-dir", "--out", "--output-dir", "--png", "--scratch", "--gif", "--markdown", "--images",
                  "--keep", "--output")


def _paths(args: list[str], options: tuple[str, ...]) -> tuple[list[str], list[str]]:
    """(inputs, outputs): path words of ``args``, outputs being the values of ``options`` (and of a node's
    ``-p output:=`` / ``-p run_dir:=``)."""
    inputs, outputs = [], []
    for i, word in enumerate(args):
        if re.match(r"(output|run_dir):=.", word):
            outputs.append(word.partition(":=")[2])
            continue
        value = word.partition("=")[2] if "=" in word and not _is_path(word) else word
        if not _is_path(value) or (":=" in word and value.startswith("/")):   # -r __ns:=/game_1: a ROS name
            continue
        (outputs if i and args[i - 1] in options else inputs).append(value)
    return inputs, outputs


@dataclass
class Result:
    code: int
    output: str
    seconds: float


TIMED_OUT = -1000


def _tail(text: str, lines: int = 6) -> str:
    return " | ".join(line.strip() for line in text.strip().splitlines()[-lines:] if line.strip())


class _Expired(BaseException):
    """Raised by SIGALRM in an in-process command that ran past its timeout."""


def run_in_process(target: str, args: list[str], cwd: Path, home: Path, timeout: float) -> Result:
    """``main(args)`` of ``target`` with cwd and $HOME of the scratch view; the worker's state restored after."""
    import logging
    function = _load(target)
    buffer = io.StringIO()
    saved_cwd, saved_argv, saved_env = os.getcwd(), list(sys.argv), dict(os.environ)
    saved_signals = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGALRM)}
    saved_affinity = os.sched_getaffinity(0)
    torch = sys.modules.get("torch")
    saved_threads = torch.get_num_threads() if torch is not None else len(saved_affinity)
    root_handlers = list(logging.getLogger().handlers)

    def expire(*_: Any) -> None:
        raise _Expired()

    start = time.monotonic()
    code = 0
    try:
        os.chdir(cwd)
        os.environ["HOME"] = str(home)
        for key, value in CACHES.items():
            os.environ.setdefault(key, value)
        sys.argv = [target.partition(":")[0], *args]
        signal.signal(signal.SIGALRM, expire)
        signal.setitimer(signal.ITIMER_REAL, timeout)
        with warnings.catch_warnings(), contextlib.redirect_stdout(buffer), contextlib.redirect_stderr(buffer):
            try:
                returned = function(list(args))
                code = 0 if returned is None else int(returned)
            except SystemExit as stop:
                code = stop.code if isinstance(stop.code, int) else (0 if stop.code is None else 1)
                if not isinstance(stop.code, (int, type(None))):
                    buffer.write(f"{stop.code}\n")
    except _Expired:
        code = TIMED_OUT
    except Exception:   # a traceback is a failure of the documented command
        code = 1
        buffer.write(traceback.format_exc())
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        for number, handler in saved_signals.items():
            signal.signal(number, handler)
        os.chdir(saved_cwd)
        sys.argv = saved_argv
        os.environ.clear()
        os.environ.update(saved_env)
        os.sched_setaffinity(0, saved_affinity)
        if "torch" in sys.modules:
            sys.modules["torch"].set_num_threads(saved_threads)
        logging.getLogger().handlers[:] = root_handlers
    return Result(code, buffer.getvalue(), time.monotonic() - start)


def _subprocess_env(scratch: Scratch, extra: dict[str, str]) -> dict[str, str]:
    """A fresh shell's environment: no .venv/bin on PATH (a block must say .venv/bin/), $HOME in the scratch."""
    venv_bin = {str(REPO / ".venv" / "bin"), str(Path(sys.prefix) / "bin")}
    path = os.pathsep.join(p for p in os.environ.get("PATH", "").split(os.pathsep) if p not in venv_bin)
    env = {**CACHES, **os.environ, "PATH": path, "HOME": str(scratch.home), "PYTHONUNBUFFERED": "1"}
    env.pop("VIRTUAL_ENV", None)
    return {**env, **extra}


def _stop(process: subprocess.Popen, signum: int, wait: float) -> int | None:
    """Send ``signum`` to the process group; its exit status, or None if it did not exit within ``wait``."""
    with contextlib.suppress(ProcessLookupError):
        os.killpg(process.pid, signum)
    try:
        return process.wait(wait)
    except subprocess.TimeoutExpired:
        return None


def run_subprocess(argv: list[str], scratch: Scratch, env: dict[str, str], timeout: float) -> Result:
    log = scratch.new_log()
    start = time.monotonic()
    with log.open("w") as handle:
        try:
            process = subprocess.Popen(argv, cwd=scratch.cwd, env=_subprocess_env(scratch, env), stdout=handle,
                                       stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, start_new_session=True)
        except OSError as error:   # not found / not executable: as a shell would say
            return Result(127, f"{argv[0]}: {error.strerror}", 0.0)
        try:
            code = process.wait(timeout)
        except subprocess.TimeoutExpired:
            code = TIMED_OUT
            if _stop(process, signal.SIGINT, 10.0) is None:
                _stop(process, signal.SIGKILL, 10.0)
    return Result(code, log.read_text(errors="replace"), time.monotonic() - start)


class GraphProbe:
    """A node of this test in a ROS domain, to see a started node appear on the graph: every rclpy node publishes
    /rosout, and each publisher has its own gid (a node name can linger on the graph after its process ended)."""

    def __init__(self) -> None:
        self._probes: dict[int, tuple[Any, Any]] = {}

    def publishers(self, domain: int) -> dict[bytes, str]:
        """gid -> node name of every /rosout publisher in ``domain``."""
        import rclpy
        from rclpy.context import Context
        if domain not in self._probes:
            context = Context()
            rclpy.init(context=context, domain_id=domain)
            self._probes[domain] = (context, rclpy.create_node(f"doc_commands_probe_{os.getpid()}",
                                                               context=context))
        node = self._probes[domain][1]
        return {bytes(info.endpoint_gid): f"{info.node_namespace.rstrip('/')}/{info.node_name}"
                for info in node.get_publishers_info_by_topic("/rosout") if info.node_name != node.get_name()}

    def close(self) -> None:
        import rclpy
        for context, node in self._probes.values():
            node.destroy_node()
            rclpy.try_shutdown(context=context)
        self._probes.clear()


def run_node(argv: list[str], scratch: Scratch, env: dict[str, str], probe: GraphProbe) -> Result:
    """Start a node, wait until it is on the ROS graph, SIGINT it: it must have stayed up and exit 0."""
    domain = int(env.get("ROS_DOMAIN_ID", os.environ.get("ROS_DOMAIN_ID", "0")))
    before = probe.publishers(domain)
    log = scratch.new_log()
    start = time.monotonic()
    with log.open("w") as handle:
        process = subprocess.Popen(argv, cwd=scratch.cwd, env=_subprocess_env(scratch, env), stdout=handle,
                                   stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, start_new_session=True)
        appeared: set[str] = set()
        while time.monotonic() - start < NODE_ALIVE_S and process.poll() is None and not appeared:
            time.sleep(0.2)
            appeared = {name for gid, name in probe.publishers(domain).items() if gid not in before}
        if process.poll() is not None:
            code = process.returncode or 1
            note = f"exited ({process.returncode}) by itself, before it was stopped\n"
        elif not appeared:
            code = TIMED_OUT
            note = f"not on the ROS graph (domain {domain}) after {NODE_ALIVE_S:.0f} s\n"
            _stop(process, signal.SIGKILL, 10.0)
        else:
            time.sleep(NODE_SETTLE_S)
            stopped = _stop(process, signal.SIGINT, NODE_STOP_S)
            code = TIMED_OUT if stopped is None else stopped
            note = (f"on the graph as {', '.join(sorted(appeared))}; " +
                    ("did not exit after SIGINT\n" if stopped is None else f"exit {stopped} after SIGINT\n"))
            if stopped is None:
                _stop(process, signal.SIGKILL, 10.0)
    return Result(code, note + log.read_text(errors="replace"), time.monotonic() - start)


# ------------------------------------------------------------------------------------------------ scratch views
# documented commands write into these (the test ledger: a documented `--split test` evaluation appends its row)
SCRATCH_COPIED = ("bags", "policy_node", "tools", "docs/images", "docs/results_data/test_ledger.jsonl")
SCRATCH_LINKED_IN_COPIES = ("tools/bootstrap.py", "tools/lock.py")  # make's bootstrap works on the repository's venv
SCRATCH_LEFT_OUT = ("runs", ".pytest_cache", "__pycache__")   # .git is linked: tools read the history


def unshare(root: Path, output: str) -> None:
    """Make ``output`` (relative to the scratch view ``root``) a path of the view's own: each folder on the way that
    links into the repository becomes a folder of links, and a file there a copy. A shortened documented command that
    writes where a committed result lies (``--out docs/results_data/…``) then writes into the view, never through a
    link into the repository."""
    path = Path(output)
    if path.is_absolute() or ".." in path.parts:
        return
    here = root
    for part in path.parts:
        here = here / part
        if not here.is_symlink():
            if not here.exists():
                return
            continue
        source = here.resolve()
        if REPO not in source.parents and source != REPO:
            return
        here.unlink()
        if source.is_dir():
            here.mkdir()
            for child in source.iterdir():
                (here / child.name).symlink_to(child)
        else:
            shutil.copy2(source, here)
            return


def make_scratch(root: Path) -> Path:
    """A view of the repository in ``root``: entries symlinked, except SCRATCH_COPIED (copied, so a write does not
    reach the repository through a link), a fresh runs/ and home/, and the FIXTURE_FILES."""
    root.mkdir(parents=True)
    ignore = shutil.ignore_patterns("__pycache__", "recording_*")

    def place(source: Path, target: Path) -> None:
        rel = source.relative_to(REPO).as_posix()
        if rel in SCRATCH_COPIED:
            shutil.copytree(source, target, ignore=ignore) if source.is_dir() else shutil.copy2(source, target)
        elif any(c.startswith(rel + "/") for c in SCRATCH_COPIED):
            target.mkdir()
            for child in source.iterdir():
                place(child, target / child.name)
        else:
            target.symlink_to(source)

    for entry in REPO.iterdir():
        if entry.name not in SCRATCH_LEFT_OUT:
            place(entry, root / entry.name)
    for rel in SCRATCH_LINKED_IN_COPIES:
        (root / rel).unlink()
        (root / rel).symlink_to(REPO / rel)
    for name, source in FIXTURE_FILES.items():
        shutil.copy2(REPO / source, root / name)
    (root / "runs").mkdir()
    (root / "home").mkdir()
    return root


@dataclass
class Scratch:
    root: Path
    cwd: Path = field(init=False)
    logs: int = 0
    inline_views: int = 0

    def __post_init__(self) -> None:
        self.cwd = self.root

    @property
    def home(self) -> Path:
        return self.root / "home"

    def new_log(self) -> Path:
        self.logs += 1
        (self.root / "home" / "logs").mkdir(exist_ok=True)
        return self.root / "home" / "logs" / f"{self.logs:03d}.log"

    @contextlib.contextmanager
    def fresh_runs(self, fixture_run: Path) -> Iterator[None]:
        """An inline example: the same view with its own runs/, in which what the doc's blocks made is linked (an
        example may read it; what it writes is its own)."""
        self.inline_views += 1
        inline = self.root / "home" / f"inline_{self.inline_views:03d}"
        inline.mkdir()
        for entry in self.root.iterdir():
            if entry.name not in ("runs", "home"):
                (inline / entry.name).symlink_to(entry)
        (inline / "home").symlink_to(self.root / "home")
        (inline / "runs").mkdir()
        for made in (self.root / "runs").iterdir():
            (inline / "runs" / made.name).symlink_to(made)
        self._place_fixture(inline, fixture_run)
        self.cwd = inline
        try:
            yield
        finally:
            self.cwd = self.root

    def _place_fixture(self, root: Path, fixture_run: Path) -> None:
        target = root / FIXTURE_RUN
        target.parent.mkdir(parents=True, exist_ok=True)
        if not target.exists():
            target.symlink_to(fixture_run)

    def place_fixture(self, fixture_run: Path) -> None:
        self._place_fixture(self.root, fixture_run)


def doc_order(doc: str) -> list[DocCommand]:
    """A doc's commands in the order its test runs them: blocks first, then inline spans (prose may name what the
    blocks produce)."""
    return sorted((c for c in DOC_COMMANDS if c.where.split(":")[0] == doc), key=lambda c: c.inline)


def read_later(command: DocCommand, argv: list[str]) -> list[str]:
    """The outputs of ``argv`` (dedup_key's words, so `make run ARGS=… --output-dir D` counts) that a later command
    of its doc names."""
    outputs = _paths(list(dedup_key(argv)), OUTPUT_OPTIONS)[1]
    order = doc_order(command.where.split(":")[0])
    later = order[order.index(command) + 1:] if command in order else []
    def names(word: str, output: str) -> bool:   # the output or a path inside it, also as a KEY=/NAME:= value
        output = output.rstrip("/")
        return any(v == output or v.startswith(output + "/")
                   for v in (word, word.partition("=")[2], word.partition(":=")[2]))

    return [o for o in outputs if any(names(w, o) for c in later for a in c.argvs for w in a)]


# ---------------------------------------------------------------------------------------------------- the runs
@dataclass
class Done:
    where: str
    command: str
    how: str
    seconds: float = 0.0
    problem: str = ""


def _expand_home(word: str, home: Path) -> str:
    """The shell's tilde expansion: a word starting with ~/ (or VAR=~/…)."""
    if word == "~" or word.startswith("~/"):
        return str(home) + word[1:]
    return word


def _resolve_ellipsis(word: str, cwd: Path) -> str:
    """`RUN/checkpoints/step_…`: the path of that pattern that exists (the newest)."""
    if "…" not in word or "/" not in word:
        return word
    matches = sorted(cwd.glob(word.replace("…", "*")))
    return str(matches[-1].relative_to(cwd)) if matches else word


def _resume_one_update(args: list[str], cwd: Path) -> list[str]:
    run_dir = cwd / args[args.index("--resume") + 1]
    summary = run_dir / "summary.json"
    steps = json.loads(summary.read_text())["env_steps"] if summary.is_file() else 0
    return args + ["--set", f"total_env_steps={steps + 1}"]


class DocRunner:
    """Runs one doc's commands in order in one scratch view (module docstring, 4)."""

    def __init__(self, doc: str, scratch: Scratch, fixture_run: Path, probe: GraphProbe,
                 other_docs: bool = True) -> None:
        """``other_docs``: skip what another doc runs (RUN_ELSEWHERE, SHAPE_ELSEWHERE)."""
        self.doc = doc
        self.run_elsewhere = RUN_ELSEWHERE if other_docs else {}
        self.shape_elsewhere = SHAPE_ELSEWHERE if other_docs else {}
        self.scratch = scratch
        self.fixture_run = fixture_run
        self.probe = probe
        self.ran: dict[tuple[str, ...], str] = {}            # key -> where it ran
        self.shapes: dict[tuple[str, ...], tuple[str, list[str]]] = {}   # shape -> (where, argv as run)
        self.done: list[Done] = []
        scratch.place_fixture(fixture_run)

    def do(self, command: DocCommand, argv: list[str]) -> None:
        step = plan(argv, command.inline)
        text = " ".join(argv)
        if step.kind == "skip":
            return
        if step.kind == "unlisted":
            self.done.append(Done(command.where, text, "unlisted", problem=step.reason))
            return
        try:
            checked = step.run()
        except DocCommandError as error:
            self.done.append(Done(command.where, text, "parse", problem=str(error)))
            return
        if MENTIONED in checked or (command.inline and _names_only(argv)):
            self.done.append(Done(command.where, text, MENTIONED))
            return
        problem = self._as_written(argv, command)
        if problem:
            self.done.append(Done(command.where, text, "as written", problem=problem))
            return
        reason = parse_only_reason(argv)
        if reason:
            self.done.append(Done(command.where, text, f"parsed only: {reason}"))
            return
        env = _env_prefix(argv)
        short = shorten(argv)
        key = dedup_key(argv)
        elsewhere = self.run_elsewhere.get(key)
        if key in self.ran or (elsewhere and not elsewhere.startswith(self.doc + ":")):
            self.done.append(Done(command.where, text, f"same as {self.ran.get(key) or elsewhere}"))
            return
        self.ran[key] = command.where
        shape = shape_key(argv)
        if shape is not None:
            why = _matching(SAME_SHAPE, short)[1][0]
            outputs = read_later(command, argv)   # what a later command reads must be made (or copied)
            elsewhere = self.shape_elsewhere.get(shape, "")
            if shape in self.shapes and (not outputs or short[0] == "dynenv-train"):
                self.done.append(self._same_shape(command.where, text, short, *self.shapes[shape], why))
                return
            if not outputs and elsewhere and not elsewhere.startswith(self.doc + ":"):
                self.done.append(self._same_shape(command.where, text, short, elsewhere, [], why))
                return
            self.shapes.setdefault(shape, (command.where, short))
        if command.inline:
            with self.scratch.fresh_runs(self.fixture_run):
                self.done.append(self._run(command.where, text, short, env))
        else:
            self.done.append(self._run(command.where, text, short, env))

    def _as_written(self, argv: list[str], command: DocCommand) -> str:
        """A block command must run from a fresh shell: its program is .venv/bin/…, make or a listed tool."""
        if command.inline:
            return ""
        program = _strip_prefixes(argv)[0]
        if program in TOOLS or program in NODES or program in ("python", "python3", "pytest"):
            return (f"`{program}` is not on PATH in a fresh shell (the venv is not activated): write "
                    f"`.venv/bin/{program}`")
        return ""

    def _same_shape(self, where: str, text: str, short: list[str], first_where: str, first: list[str],
                    why: str) -> Done:
        """Not run again: its inputs must exist; a training's run directory is a copy of the first one's."""
        inputs, outputs = _paths(short, OUTPUT_OPTIONS)
        first_outputs = _paths(first, OUTPUT_OPTIONS)[1]
        missing = [p for p in inputs if not (self.scratch.cwd / p).exists()]
        if missing:
            return Done(where, text, "same shape", problem=f"its input {', '.join(missing)} does not exist")
        for output, source in zip(outputs, first_outputs):
            if (self.scratch.cwd / source).is_dir():
                shutil.copytree(self.scratch.cwd / source, self.scratch.cwd / output, symlinks=True)
        return Done(where, text, f"same shape as {first_where}: {why}")

    def _run(self, where: str, text: str, short: list[str], env: dict[str, str]) -> Done:
        cwd = self.scratch.cwd
        home = self.scratch.home
        args = [_resolve_ellipsis(_expand_home(w, home), cwd) for w in short]
        for output in _paths(args, OUTPUT_OPTIONS)[1]:
            unshare(cwd, output)
        if args[0] == "dynenv-train" and "--resume" in args:
            args = _resume_one_update(args, cwd)
        shown = shlex.join(args)
        timeout = TIMEOUT_S
        match = _matching(LONG_TIMEOUT_S, args)
        if match:
            timeout = match[1]
        target = _matching(IN_PROCESS, args)
        helps = "-h" in args or "--help" in args
        if target is not None and not env:
            first = 3 if target[0][0] == "python" else 1
            result = run_in_process(target[1], args[first:], cwd, home, timeout)
            how = "in-process"
        elif args[0] in NODES and not helps:
            result = run_node([str(cwd / ".venv" / "bin" / args[0]), *args[1:]], self.scratch, env, self.probe)
            how = "node"
        elif args[:2] == ["python", "-m"] and _module_targets().get(args[2], ("", ""))[0] == "node" and not helps:
            result = run_node([sys.executable, *args[1:]], self.scratch, env, self.probe)
            how = "node"
        else:
            program = args[0]
            if program == "python":
                program = sys.executable
            elif program in TOOLS or program in NODES:
                program = str(cwd / ".venv" / "bin" / program)
            result = run_subprocess([program, *args[1:]], self.scratch, env, timeout)
            how = "subprocess"
        problem = ""
        if result.code == TIMED_OUT:
            problem = f"ran past its timeout ({timeout:.0f} s): {_tail(result.output)}"
        elif result.code != 0:
            problem = f"exit status {result.code}: {_tail(result.output)}"
        return Done(where, f"{text}\n      ran: {shown}", how, result.seconds, problem)

    def report(self) -> str:
        lines = []
        for done in self.done:
            seconds = f"{done.seconds:6.1f} s" if done.seconds else "       "
            lines.append(f"{seconds}  {done.where}  [{done.how}]  {done.command}" +
                         (f"\n      PROBLEM: {done.problem}" if done.problem else ""))
        total = sum(d.seconds for d in self.done)
        return "\n".join(lines) + f"\n{total:.1f} s in commands"


def _run_elsewhere() -> tuple[dict[tuple[str, ...], str], dict[tuple[str, ...], str]]:
    """Commands (and shapes) that run in an earlier doc and name no output another command of their doc may read:
    {key: where}, {shape: where}."""
    first: dict[tuple[str, ...], str] = {}
    shapes: dict[tuple[str, ...], str] = {}
    made: dict[tuple[str, ...], str] = {}
    for command in DOC_COMMANDS:
        for argv in command.argvs:
            if plan(argv, command.inline).kind != "check" or parse_only_reason(argv) or not _strip_prefixes(argv):
                continue
            short = shorten(argv)
            shape = shape_key(argv)
            if shape is not None:
                (made if read_later(command, argv) else shapes).setdefault(shape, command.where)
            if any("runs/" in w or w.startswith("~") or "=~" in w or ":=~" in w for w in short) or \
                    short[0] == "dynenv-keys":   # writes into $HOME by default: each doc has its own
                continue
            first.setdefault(dedup_key(argv), command.where)
    return first, {**shapes, **made}   # one that writes an output runs in its doc: the others need not


# ------------------------------------------------------------------------------------------------------ tests
DOC_COMMANDS = all_doc_commands()
RUN_ELSEWHERE, SHAPE_ELSEWHERE = _run_elsewhere()
# The order of the doc tests, so that `pytest -n 2` on this file ends both workers together: xdist's load scheduling
# gives each worker a first chunk of six consecutive tests (two unit tests and four docs, then six docs), so the docs
# are grouped in two halves of about equal time (measured on this 2-core machine). Docs not listed follow.
DOC_TEST_ORDER = ["docs/ros_graph.md", "README.md", "docs/driving.md", "docs/deploy.md",   # 85 + 58 + 23 + 27 s
                  "docs/results.md", "docs/training.md", "docs/setup.md", "docs/benchmarks.md",   # 70 + 60 + 4 + 50 s
                  "docs/perception.md"]
DOCS = sorted((path.relative_to(REPO).as_posix() for path in DOC_FILES),
              key=lambda doc: DOC_TEST_ORDER.index(doc) if doc in DOC_TEST_ORDER else len(DOC_TEST_ORDER))


def test_the_docs_show_commands() -> None:
    where = {c.where.split(":")[0] for c in DOC_COMMANDS}
    assert "README.md" in where and len(DOC_COMMANDS) > 20, DOC_COMMANDS
    assert any(c.text.startswith("make run") for c in DOC_COMMANDS)


def test_every_doc_command_is_run_or_listed() -> None:
    unlisted = [f"{c.where}: {' '.join(argv)}" for c in DOC_COMMANDS for argv in c.argvs
                if plan(argv, c.inline).kind == "unlisted"]
    assert not unlisted, ("documented commands with no checker: add one to test/test_doc_commands.py or list them "
                          "in SKIPPED_EXTERNAL / SHELL_SYNTAX / MENTIONS with the reason:\n" + "\n".join(unlisted))


@pytest.fixture(scope="module")
def fixture_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The run directory the docs' RUN stands for: `dynenv-train --config quick`, shortened, with a checkpoint."""
    root = tmp_path_factory.mktemp("doc_fixture")
    result = run_in_process(IN_PROCESS[("dynenv-train",)], _short_train(
        ["--config", "quick", "--run-dir", str(root / "quick"), "--no-progress"]), REPO, root, TIMEOUT_S)
    assert result.code == 0, result.output
    return root / "quick"


@pytest.fixture(scope="module")
def graph_probe() -> Iterator[GraphProbe]:
    probe = GraphProbe()
    yield probe
    probe.close()


@pytest.mark.parametrize("doc", DOCS)
def test_doc_commands_work_as_written(doc: str, tmp_path: Path, fixture_run: Path, graph_probe: GraphProbe) -> None:
    runner = DocRunner(doc, Scratch(make_scratch(tmp_path / "view")), fixture_run, graph_probe)
    for command in doc_order(doc):
        for argv in command.argvs:
            runner.do(command, argv)
    print(runner.report())
    problems = [d for d in runner.done if d.problem]
    if problems:
        pytest.fail(f"{len(problems)} command(s) of {doc} do not work as written:\n" + "\n".join(
            f"{d.where}: `{d.command}` [{d.how}]: {d.problem}" for d in problems), pytrace=False)


# --- a full-ROS command shows its venv equivalent beside it ----------------------------------------------------------
def _section(doc: str, line: int) -> tuple[int, int]:
    """The lines of the markdown section (heading to heading) that holds ``line``."""
    text = (REPO / doc).read_text(encoding="utf-8").split("\n")
    fenced = False
    headings = [0]
    for number, content in enumerate(text, 1):
        if re.match(r"^\s*(```|~~~)", content):
            fenced = not fenced
        elif not fenced and content.startswith("#"):
            headings.append(number)
    start = max(h for h in headings if h <= line)
    return start, min([h for h in headings if h > line] + [len(text) + 1])


def _venv_form(argv: list[str]) -> list[str] | None:
    """What a venv equivalent of the full-ROS command ``argv`` runs (normalised), None for one it has no form of."""
    argv = _strip_prefixes(argv)
    if argv[:3] == ["ros2", "run", "dynenv_ros"]:
        return argv[3:]
    if argv[:2] == ["ros2", "service"] and argv[2:3] == ["call"]:
        return ["python", "tools/ros2_service_call.py", *argv[3:]]
    if argv[:2] == ["ros2", "launch"] and argv[3:4] == ["dynenv.launch.py"]:
        return ["make", "run"]   # any game of the main job
    if argv[:2] == ["ros2", "launch"]:
        return ["<node>"]        # a node's launch file: the node, started with the same parameters
    return None


def _as_venv(command: DocCommand, argv: list[str]) -> list[str] | None:
    """A documented command as the venv form it is: `python -m NODE_MODULE …` is NODE …"""
    if _strip_prefixes(argv)[:1] == ["ros2"]:
        return None
    normal = _normal(argv)
    if normal[:2] == ["python", "-m"] and _module_targets().get(normal[2:3][0] if normal[2:] else "", ("",))[0] == \
            "node":
        return [_module_targets()[normal[2]][1], *normal[3:]]
    return normal


def test_every_ros2_command_shows_its_venv_equivalent_beside_it() -> None:
    """"Where a ros2 command has no equivalent in the venv, the docs give the venv command beside it": in the same
    section (`ros2 run dynenv_ros NODE ARGS` -> `.venv/bin/NODE ARGS`, `ros2 service call` ->
    tools/ros2_service_call.py with the same arguments) or as a `# venv:` comment on its line (`ros2 launch` of the
    main job's dynenv.launch.py -> a `make run`; of a node's launch file -> that node's venv command)."""
    missing = []
    for command in DOC_COMMANDS:
        for argv in command.argvs:
            wanted = _venv_form(argv) if plan(argv, command.inline).kind == "check" else None
            if wanted is None:
                continue
            doc, line = command.where.split(":")[0], int(command.where.split(":")[1].split("#")[0])
            start, end = _section(doc, line)
            beside = [_as_venv(c, a) for c in DOC_COMMANDS for a in c.argvs
                      if c.where.split(":")[0] == doc and start <= int(c.where.split(":")[1].split("#")[0]) < end]
            if wanted == ["make", "run"]:
                ok = any(c.venv_comment and c.where.split("#")[0] == command.where.split("#")[0]
                         and _normal(c.argvs[0])[:2] == ["make", "run"] for c in DOC_COMMANDS)
            elif wanted == ["<node>"]:
                ok = any(c.venv_comment and c.where.split("#")[0] == command.where.split("#")[0]
                         and _normal(c.argvs[0])[:1] and _normal(c.argvs[0])[0] in NODES for c in DOC_COMMANDS)
            else:
                ok = wanted in beside
            if not ok:
                missing.append(f"{command.where}: {' '.join(argv)}  (venv: {' '.join(wanted)})")
    assert not missing, "full-ROS commands without their venv equivalent beside them:\n" + "\n".join(missing)


def test_the_docs_venv_service_calls_reach_the_node(tmp_path: Path, graph_probe: GraphProbe) -> None:
    """The docs' signed service calls (`dynenv-keys call`, issue 43) answer success, called as documented, against
    the policy node deploy.md starts with the operator's key (as documented), after deploy.md's documented
    `dynenv-keys operator` and `dynenv-keys sign-file`; and the docs' plain venv calls (tools/ros2_service_call.py),
    if any, answer too."""
    signed = [a for c in DOC_COMMANDS for a in c.argvs if _normal(a)[:2] == ["dynenv-keys", "call"] and len(a) > 2]
    plain = [a for c in DOC_COMMANDS for a in c.argvs if _normal(a)[:2] == ["python", "tools/ros2_service_call.py"]]
    assert {_normal(a)[2] for a in signed} == {"/policy_node/load_policy", "/policy_node/accept_older_weights"}, signed
    deploy = [a for c in DOC_COMMANDS for a in c.argvs if c.where.startswith("docs/deploy.md") and not c.inline]
    node = next(a for a in deploy if _normal(a)[:1] == ["policy_node"] and "checkpoint:=agent.onnx" in a
                and any("trusted_operator_keys" in w for w in a))
    setup = [a for a in deploy if _normal(a)[:2] in (["dynenv-keys", "operator"], ["dynenv-keys", "sign-file"])]
    assert [_normal(a)[1] for a in setup] == ["operator", "sign-file"], setup
    scratch = Scratch(make_scratch(tmp_path / "view"))
    for argv in setup:
        result = run_subprocess([str(scratch.cwd / ".venv" / "bin" / "dynenv-keys"), *_normal(argv)[1:]], scratch,
                                {}, TIMEOUT_S)
        assert result.code == 0, (argv, result.output)
    log = scratch.new_log()
    before = graph_probe.publishers(int(os.environ.get("ROS_DOMAIN_ID", "0")))
    with log.open("w") as handle:
        process = subprocess.Popen([str(scratch.cwd / ".venv" / "bin" / "policy_node"), *_normal(node)[1:]],
                                   cwd=scratch.cwd, env=_subprocess_env(scratch, {}), stdout=handle,
                                   stderr=subprocess.STDOUT, start_new_session=True)
    try:
        deadline = time.monotonic() + NODE_ALIVE_S
        while set(graph_probe.publishers(int(os.environ.get("ROS_DOMAIN_ID", "0")))) <= set(before):
            assert time.monotonic() < deadline and process.poll() is None, log.read_text()
            time.sleep(0.2)
        for call in signed:
            args = _normal(call)
            result = run_subprocess([str(scratch.cwd / ".venv" / "bin" / "dynenv-keys"), *args[1:], "--timeout",
                                     "25"], scratch, {}, TIMEOUT_S)
            assert result.code == 0 and "success: true" in result.output, (args, result.output)
        for call in plain:
            args = _normal(call)
            result = run_subprocess([sys.executable, *args[1:], "--timeout", "60"], scratch, {}, TIMEOUT_S)
            assert result.code == 0 and "response:" in result.output, (args, result.output)
    finally:
        _stop(process, signal.SIGINT, NODE_STOP_S)
        _stop(process, signal.SIGKILL, 5.0)


def test_a_documented_output_where_a_committed_result_lies_is_written_in_the_scratch_view(tmp_path: Path) -> None:
    """A shortened command's --out into docs/results_data must not reach the repository through the view's links
    (it once overwrote committed evaluations with 1-episode ones)."""
    root = make_scratch(tmp_path / "view")
    committed = "docs/results_data/issue39/random_vs_random_s100-104.json"
    before = (REPO / committed).read_bytes()
    unshare(root, committed)
    assert not (root / committed).is_symlink() and (root / committed).read_bytes() == before
    (root / committed).write_text("{}")
    new = "docs/results_data/issue39/not_committed/out.json"
    unshare(root, new)
    (root / new).parent.mkdir()
    (root / new).write_text("{}")
    assert (REPO / committed).read_bytes() == before and not (REPO / new).parent.exists()
    assert (root / "docs" / "results_data" / "issue26").is_symlink()        # the rest of the view still links


def test_the_venv_service_call_refuses_a_wrong_request(tmp_path: Path) -> None:
    scratch = Scratch(make_scratch(tmp_path / "view"))
    result = run_subprocess([sys.executable, "tools/ros2_service_call.py", "/policy_node/load_policy",
                             "dynenv_msgs/srv/LoadPolicy", "{no_such_field: 1}"], scratch, {}, TIMEOUT_S)
    assert result.code == 2 and "no field no_such_field" in result.output, result.output


# --- the extraction, the checkers and the runner are real: each refuses a made-up wrong command ----------------------
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
        "ros2 launch dynenv_ros dynenv.launch.py n_cars:=3   # venv: make run ARGS=\"--set n_cars=3\"\n"
        "```\n"
        "```python\nimport os\n```\n")
    commands = extract(path, "doc.md")
    by_line = {c.where.split(":", 1)[1]: c for c in commands}
    assert by_line["1"].argvs == [["dynenv-bag", "info"], ["dynenv-bag", "echo"]]
    assert by_line["1#2"].argvs == [["ros2", "run", "dynenv_ros", "sim_node"]]
    assert by_line["6"].argvs == [["dynenv-eval", "random", "--opponent", "random", "--seeds", "0", "1"]]
    assert by_line["10"].argvs == [["dynenv-train", "--config", "a", "--run-dir", "runs/a_s1"],
                                   ["dynenv-train", "--config", "b", "--set", "k=v", "--run-dir", "runs/b_s1"]]
    assert by_line["12"].argvs == [["ros2", "launch", "dynenv_ros", "dynenv.launch.py", "n_cars:=3"]]
    assert by_line["12#2"].argvs == [["make", "run", "ARGS=--set n_cars=3"]] and by_line["12#2"].venv_comment
    assert set(by_line) == {"1", "1#2", "6", "9", "10", "12", "12#2"}
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


def test_shortening_is_the_documented_table() -> None:
    assert shorten(["taskset", "-c", "1", ".venv/bin/dynenv-eval", "random", "--episodes", "10", "--seeds", "0",
                    "1"]) == ["dynenv-eval", "random", "--episodes", "1", "--seeds", "0", "1", "--episode-seconds",
                              "2"]
    assert shorten(["dynenv-eval", "training-best", "runs/a", "--window", "10"]) == [
        "dynenv-eval", "training-best", "runs/a", "--window", "10"]
    assert shorten(["dynenv-train", "--config", "async", "--set", "total_env_steps=700000"]) == [
        "dynenv-train", "--config", "async", "--set", "total_env_steps=700000", "--set", "total_env_steps=1",
        "--set", "num_envs=2", "--set", "workers=1"]
    assert shorten(["make", "run", "ARGS=--set scenario=driving"]) == [
        "make", "run", "ARGS=--set scenario=driving --set duration_s=2"]
    assert shorten(["ros2", "run", "dynenv_ros", "sim_node", "--ros-args"]) == ["sim_node", "--ros-args"]
    assert shorten(["dynenv-bench", "sim", "--steps=4000", "--json"]) == [
        "dynenv-bench", "sim", "--steps", "10", "--json", "--repeat", "1"]
    assert shape_key(["dynenv-train", "--seed", "1", "--run-dir", "runs/x_s1"]) == \
        shape_key(["dynenv-train", "--seed", "2", "--run-dir", "runs/y_s2"])
    assert shape_key(["dynenv-train", "--set", "variant=pred"]) != shape_key(["dynenv-train", "--set", "variant=icm"])


def test_the_scratch_view_keeps_writes_out_of_the_repository(tmp_path: Path) -> None:
    root = make_scratch(tmp_path / "view")
    for rel in SCRATCH_COPIED:                     # folders, and the ledger (a file)
        assert (root / rel).exists() and not (root / rel).is_symlink(), rel
    assert (root / "docs" / "results_data" / "test_ledger.jsonl").is_file()
    assert (root / "config").resolve() == REPO / "config"                         # read-only: linked
    assert (root / "tools" / "bootstrap.py").resolve() == REPO / "tools" / "bootstrap.py"
    assert not (root / "bags" / "sample_2v2_realistic_30s" / "metadata.yaml").is_symlink()
    assert list((root / "runs").iterdir()) == [] and (root / "agent.onnx").is_file()


def test_the_runner_runs_and_refuses_wrong_commands(tmp_path: Path, graph_probe: GraphProbe) -> None:
    runner = DocRunner("doc.md", Scratch(make_scratch(tmp_path / "view")), tmp_path, graph_probe, other_docs=False)
    commands = {
        "1": ".venv/bin/dynenv-bag echo bags/sample_2v2_realistic_30s --topic /clock --limit 2",   # runs
        "2": ".venv/bin/dynenv-bag echo bags/sample_2v2_realistic_30s --topic /nothing --limit 2",  # exit 2
        "3": "dynenv-bag info bags/sample_2v2_realistic_30s",       # a block's program must be .venv/bin/…
        "4": ".venv/bin/dynenv-bag echo bags/sample_2v2_realistic_30s --topic /clock --limit 2",   # done above
        "5": ".venv/bin/sim_node --ros-args -p players_per_team:=1",  # a node: up, SIGINT, exit 0
        "6": ".venv/bin/dynenv-keys team-secret ~/team_a.secret",    # ~ is the scratch's $HOME
    }
    for line, text in commands.items():
        command = DocCommand(f"doc.md:{line}", text, inline=False, argvs=[shlex.split(text)])
        runner.do(command, command.argvs[0])
    done = {d.where.split(":")[1]: d for d in runner.done}
    assert done["1"].how == "in-process" and not done["1"].problem
    assert "exit status 2" in done["2"].problem
    assert "not on PATH" in done["3"].problem
    assert done["4"].how == "same as doc.md:1"
    assert done["5"].how == "node" and not done["5"].problem, done["5"]
    assert not done["6"].problem and (runner.scratch.home / "team_a.secret").is_file()


if __name__ == "__main__":   # list the documented commands and how each is handled
    for doc_command in DOC_COMMANDS:
        for doc_argv in doc_command.argvs:
            step = plan(doc_argv, doc_command.inline)
            how = step.kind if step.kind != "check" else (
                f"parse only: {parse_only_reason(doc_argv)}" if parse_only_reason(doc_argv) else
                f"run: {shlex.join(shorten(doc_argv))}")
            print(f"{doc_command.where}\t{' '.join(doc_argv)}\t{how if step.kind == 'check' else step.reason}")
