"""Scenario branches outside the registry (issue 40, part 2): code that asks which world it is in instead of asking
the world (``dynenv_ros/scenarios/``, docs/decisions.md "A scenario registry").

A *scenario branch* is a line of code — comments and docstrings left out — matching ``BRANCH``:

- ``if``/``elif``/``while``/``and``/``or`` (``not``) followed by a name ending in ``driving`` (``if driving:``,
  ``if self.driving``, ``if settings.driving``),
- ``driving if`` / ``driving else`` (a conditional expression on it),
- ``scenario ==`` / ``scenario !=`` (any name or call ending in ``scenario``),
- ``== "driving"`` / ``!= "robocup"`` … against a scenario's name, canonical or legacy.

Inside (not counted): the registry itself and the two world packages, whose code is one scenario's by
definition. The issue's goal was at most ``GOAL`` lines outside; ``CEILING`` is where the count stands (none since
issue 40's restructuring), so the test fails when a branch is added."""
from __future__ import annotations

import ast
import io
import re
import tokenize
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCANNED = ("dynenv_ros", "policy_node")
INSIDE = ("dynenv_ros/scenarios/", "dynenv_ros/soccer/", "dynenv_ros/driving/")
NAMES = r"(driving|robocup|soccer|robocup_v0)"
BRANCH = re.compile(r"\b(if|elif|while|and|or) (not )?[\w.]*\bdriving\b|\bdriving (if|else)\b"
                    r"|scenario\b[)\]\"']* *[!=]=|[!=]= *[\"']" + NAMES + r"[\"']")
GOAL = 10
CEILING = 0


def code_lines(source: str) -> dict[int, str]:
    """Line number -> the line's code: comments and docstring lines dropped, the text of one-line strings blanked
    (a message saying "robocup or driving" is no branch) unless it is a scenario's name."""
    lines = dict(enumerate(source.splitlines(), 1))
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and node.body:
            first = node.body[0]
            if (isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant)
                    and isinstance(first.value.value, str)):
                for number in range(first.lineno, (first.end_lineno or first.lineno) + 1):
                    lines.pop(number, None)
    blanks: list[tuple[int, int, int, str]] = []
    text_tokens = (tokenize.STRING, getattr(tokenize, "FSTRING_MIDDLE", -1))
    for token in tokenize.generate_tokens(io.StringIO(source).readline):
        row, column = token.start
        if row not in lines:
            continue
        if token.type == tokenize.COMMENT:
            blanks.append((row, column, len(lines[row]), ""))
        elif token.type in text_tokens and token.end[0] == row and not re.fullmatch(r"[\"']" + NAMES + r"[\"']",
                                                                                     token.string):
            blanks.append((row, column, token.end[1], "_" if token.type != tokenize.STRING else '""'))
    for row, start, end, text in sorted(blanks, reverse=True):      # right to left: columns stay valid
        lines[row] = lines[row][:start] + text + lines[row][end:]
    return lines


def scenario_branches(root: Path = ROOT) -> list[str]:
    """'path:line: code' of every scenario branch outside the registry and the world packages."""
    found = []
    for package in SCANNED:
        for path in sorted((root / package).rglob("*.py")):
            relative = path.relative_to(root).as_posix()
            if relative.startswith(INSIDE):
                continue
            for number, line in code_lines(path.read_text()).items():
                if BRANCH.search(line):
                    found.append(f"{relative}:{number}: {line.strip()}")
    return found


def test_the_pattern_finds_each_kind_of_branch_and_nothing_else():
    hits = ["if driving:", "elif not self.driving:", "x = a if params.driving else b", "'cars' if driving else",
            "if scenario == 'robocup':", "if spec.scenario != \"soccer\":", "ok = cfg.get('scenario') == x",
            'kind = getattr(m, "scenario", "soccer") == "driving"', 'while mode != "robocup_v0":']
    misses = ["driving = True", "from dynenv_ros.driving import cars", "scenario = get_scenario(name)",
              "self.scenario.idle", "if scenarios:", 'name = "driving"',
              'if get_scenario(scenario).picks_agents_with != "team":']
    assert [h for h in hits if not BRANCH.search(h)] == []
    assert [m for m in misses if BRANCH.search(m)] == []


def test_comments_and_docstrings_are_not_code():
    source = ('"""if driving: a docstring"""\n\ndef f():\n    """scenario == \'x\'"""\n    return 1  # if driving\n'
              'help = "robocup or driving"\nsaid = f"{x} cars if driving else robots"\n')
    assert not any(BRANCH.search(line) for line in code_lines(source).values())


def test_scenario_branches_outside_the_registry_stay_under_the_ceiling():
    found = scenario_branches()
    assert CEILING <= GOAL
    assert len(found) <= CEILING, (f"{len(found)} scenario branches outside dynenv_ros/scenarios/ (at most "
                                   f"{CEILING}; the goal is {GOAL}): ask the scenario instead\n" + "\n".join(found))
