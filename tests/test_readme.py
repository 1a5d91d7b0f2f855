"""The README's figures are what its commands print, and its tables match the command line.

The Quick start's table of RMS errors is parsed from README.md (nothing here repeats its
numbers): each ``--method`` row is compared with what the Quick start's own command prints with
that method, and the Cramér-Rao bound row with what the seeded ``simulate`` command that made
the sample (``data/sequences/README.md``) prints, both to the printed precision. The commands'
table must list exactly the subcommands the parser has, and docs/usage.md's Python examples run.
(tests/test_repository.py checks the two commands' count, CI's copy of the second, the links
and the README's Python examples.)
"""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest
from helpers import run_python_blocks

from apcc_graph.cli.main import build_parser, main

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text(encoding="utf-8")
VENV = "python3 -m venv .venv && . .venv/bin/activate && "


def _section(title: str) -> str:
    """The README's ``## title`` section, up to the next ``## ``."""
    return README.split(f"\n## {title}\n", 1)[1].split("\n## ", 1)[0]


def _quick_start_commands() -> list[str]:
    block = re.search(r"```bash\n(.*?)```", _section("Quick start"), re.S)
    assert block is not None
    return [line for line in block.group(1).splitlines() if line.strip()]


def _table_rows(section: str) -> list[list[str]]:
    """The cells of every body row of the markdown tables in ``section``."""
    rows = []
    for line in section.splitlines():
        if line.startswith("|") and not re.fullmatch(r"\|(\s*-+\s*\|)+", line):
            rows.append([cell.strip() for cell in line.strip().strip("|").split("|")])
    return rows


def _quick_start_figures() -> dict[str, list[str]]:
    """``{"batch": ["0.067", ...], ..., "bound": [...]}`` from the Quick start's table."""
    figures = {}
    for cells in _table_rows(_section("Quick start")):
        method = re.match(r"`--method (\w+)`", cells[0])
        if method:
            figures[method.group(1)] = cells[1:]
        elif cells[0].startswith("Cramér-Rao bound"):
            figures["bound"] = cells[1:]
    return figures


def _estimate_argv(method: str, out: Path) -> list[str]:
    """The Quick start's ``apcc-graph estimate`` with ``--method`` and ``--out`` replaced."""
    argv = shlex.split(_quick_start_commands()[0].split(" && ")[-1])
    assert argv[0] == "apcc-graph"
    argv = argv[1:]
    argv[argv.index("--method") + 1] = method
    argv[argv.index("--out") + 1] = str(out)
    return argv


def _printed_rms(printed: str) -> list[str]:
    line = next(text for text in printed.splitlines() if text.startswith("RMS error"))
    return re.findall(r"segment \d+ ([0-9.]+) deg", line)


def test_the_quick_start_table_names_every_method_and_the_bound() -> None:
    figures = _quick_start_figures()
    assert sorted(figures) == ["batch", "bound", "chain", "smoother"]
    for values in figures.values():
        assert len(values) == 3 and all(re.fullmatch(r"\d+\.\d{3}", v) for v in values), values


@pytest.mark.parametrize("method", ["batch", "smoother", "chain"])
def test_quick_start_prints_the_readme_figures(method: str, tmp_path: Path, monkeypatch,
                                               capsys) -> None:
    """The Quick start's command (with ``--method`` as the row says) prints the row's RMS."""
    monkeypatch.chdir(ROOT)  # the command names data/ relative to the repository
    assert main(_estimate_argv(method, tmp_path / "out")) == 0
    assert _printed_rms(capsys.readouterr().out) == _quick_start_figures()[method]
    assert (tmp_path / "out" / "theta.csv").is_file()


def test_the_samples_bound_is_what_its_simulate_command_prints(tmp_path: Path, monkeypatch,
                                                                capsys) -> None:
    text = (ROOT / "data" / "sequences" / "README.md").read_text(encoding="utf-8")
    command = re.search(r"^\s+(apcc-graph simulate .*?)\n\n", text, re.S | re.M)
    assert command is not None
    argv = shlex.split(command.group(1).replace("\\\n", " "))[1:]
    argv[argv.index("--out") + 1] = str(tmp_path / "sample")
    monkeypatch.chdir(ROOT)
    assert main(argv) == 0
    line = next(t for t in capsys.readouterr().out.splitlines() if t.startswith("Cramer-Rao"))
    assert re.findall(r"([0-9]+\.[0-9]+)", line.split(":")[-1]) == _quick_start_figures()["bound"]


def test_quick_start_commands_have_the_expected_form() -> None:
    first, second = _quick_start_commands()
    assert second == VENV + 'python -m pip install ".[dev]" && python -m pytest'
    assert first.startswith(VENV + "python -m pip install . && apcc-graph estimate data/")
    argv = _estimate_argv("batch", Path("out"))
    assert build_parser().parse_args(argv).command == "estimate"
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8").splitlines()
    assert ci[-1].endswith(second)  # the command CI runs last


def _parser_commands(parser=None, prefix: str = "") -> set[str]:
    """Every command of the parser that runs something: ``estimate``, ``bench live``, ..."""
    import argparse

    parser = parser or build_parser()
    found: set[str] = set()
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                subs = _parser_commands(sub, f"{prefix}{name} ")
                found |= subs or {f"{prefix}{name}"}
    return found


def _readme_commands() -> list[str]:
    return [m.group(1) for cells in _table_rows(_section("Commands"))
            if (m := re.fullmatch(r"`apcc-graph ([a-z][a-z -]*)`", cells[0]))]


def test_the_commands_table_lists_every_subcommand_once() -> None:
    listed = _readme_commands()
    assert len(listed) == len(set(listed))
    assert set(listed) == _parser_commands()
    assert "bench young-tracks" in listed


def test_every_command_quoted_in_the_readme_tables_parses() -> None:
    """The examples of the commands' and the results' tables are commands the parser takes."""
    cells = [row[2] for row in _table_rows(_section("Commands"))[1:]]
    cells += [row[3] for row in _table_rows(_section("Headline results"))[1:]]
    examples = [cmd for cell in cells for cmd in re.findall(r"`(apcc-graph [^`]*)`", cell)]
    assert len(examples) > len(_readme_commands())
    parser = build_parser()
    for command in examples:
        args = parser.parse_args(shlex.split(command)[1:])
        assert callable(args.run), command


def test_the_usage_pages_python_examples_run(tmp_path: Path, monkeypatch) -> None:
    """Every ```python block of docs/usage.md runs as written, in order, from a folder that has
    the repository's data/ (as tests/test_repository.py runs the README's)."""
    namespace = run_python_blocks(ROOT / "docs" / "usage.md", tmp_path, monkeypatch)
    assert (tmp_path / "angles.png").stat().st_size > 1000
    assert len(namespace["final"]) == namespace["seq"].n_frames  # the stream's every frame
