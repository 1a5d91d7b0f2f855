"""Repository contracts: the two Quick start commands, CI running the test command, data size."""

from __future__ import annotations

import importlib
import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

from helpers import run_python_blocks

ROOT = Path(__file__).resolve().parents[1]


def quick_start_commands() -> list[str]:
    text = (ROOT / "README.md").read_text()
    section = text.split("## Quick start", 1)[1].split("\n## ", 1)[0]
    block = re.search(r"```(?:bash)?\n(.*?)```", section, re.S)
    assert block, "the Quick start section must hold a fenced code block"
    return [line for line in block.group(1).splitlines() if line.strip()]


def test_quick_start_has_exactly_two_commands() -> None:
    commands = quick_start_commands()
    assert len(commands) == 2
    assert "apcc-graph" in commands[0] and "data/" in commands[0]
    assert "pytest" in commands[1]


def test_ci_runs_the_readme_test_command_verbatim() -> None:
    ci = (ROOT / ".ci" / "run").read_text().splitlines()
    assert quick_start_commands()[1] in ci
    assert "set -euo pipefail" in ci


def test_shipped_data_stays_small() -> None:
    size = sum(p.stat().st_size for p in (ROOT / "data").rglob("*") if p.is_file())
    assert size < 10 * 1024 * 1024


def test_readme_python_examples_run(tmp_path: Path, monkeypatch) -> None:
    """Every ```python block of the README runs as written, in order, from a folder that has the
    repository's data/ (files the examples write land in tmp_path)."""
    run_python_blocks(ROOT / "README.md", tmp_path, monkeypatch)
    assert (tmp_path / "angles.png").stat().st_size > 1000


def test_readme_links_and_figure_exist() -> None:
    text = (ROOT / "README.md").read_text()
    for target in re.findall(r"\]\(([^)#]+)\)", text):
        if "://" not in target:
            assert (ROOT / target).exists(), target


def _documents() -> list[Path]:
    return [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")),
            *sorted((ROOT / "data").rglob("*.md")), *sorted((ROOT / "notebooks").glob("*.md"))]


def _resolves(dotted: str) -> bool:
    parts = dotted.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            value = importlib.import_module(".".join(parts[:cut]))
        except ModuleNotFoundError:
            continue
        try:
            for name in parts[cut:]:
                value = getattr(value, name)
        except AttributeError:
            return False
        return True
    return False


def test_module_paths_named_in_the_documents_exist() -> None:
    """Every dotted name (``apcc_graph.x.y``, ``apcc_graph.factors.x``) and source path
    (``apcc_graph/x.py``) the README and docs/ name resolves: a moved module breaks this."""
    missing = []
    for doc in _documents():
        text = doc.read_text()
        for dotted in set(re.findall(r"\b((?:apcc_graph|factors)(?:\.[A-Za-z_]\w*)+)", text)):
            if not _resolves(dotted.rstrip(".")):
                missing.append(f"{doc.relative_to(ROOT)}: {dotted}")
        for path in set(re.findall(r"\b((?:apcc_graph|factors|tests)/[\w/]+\.py)\b", text)):
            if not (ROOT / path).exists():
                missing.append(f"{doc.relative_to(ROOT)}: {path}")
    assert missing == []


def test_the_benches_robot_ships_with_the_package() -> None:
    """The benches load their robot from the package (they run from any folder after a
    non-editable install): the same file as the repository's, and declared as package data."""
    from apcc_graph.bench import ROBOT_FILE

    assert ROBOT_FILE.read_bytes() == (ROOT / "data" / "robots" / "planar_three.toml").read_bytes()
    assert ROBOT_FILE.parent == ROOT / "apcc_graph" / "bench"
    pyproject = (ROOT / "pyproject.toml").read_text()
    assert '"apcc_graph.bench" = ["*.toml"]' in pyproject


def test_the_refusal_counter_counts_raises_blocks_exits_and_parameters(tmp_path: Path) -> None:
    import sys

    sys.path.insert(0, str(ROOT / "tests"))
    try:
        from refusals import count
    finally:
        sys.path.pop(0)
    (tmp_path / "test_a.py").write_text(
        "import pytest\n"
        "@pytest.mark.parametrize('x', [1, 2, 3])\n"
        "def test_p(x):\n"
        "    with pytest.raises(ValueError):\n"
        "        int('a')\n"
        "def test_cli():\n"
        "    assert main(['x']) == 1\n"
        "    assert main(['y']) == 0\n"
        "    with pytest.warns(UserWarning):\n"
        "        pass\n"
        "def helper():\n"
        "    with pytest.raises(ValueError):\n"
        "        pass\n")
    (tmp_path / "test_b.py").write_text("def test_nothing():\n    assert True\n")
    counts = count(tmp_path)
    assert (counts["refused"], counts["warned"], counts["files"]) == (4, 1, 1)


def test_the_wheel_installs_the_factors_inside_the_package(tmp_path: Path) -> None:
    """``factors/`` stays at the top of the repository and installs as ``apcc_graph.factors``
    (through the link ``apcc_graph/factors``): no top-level ``factors`` module in the wheel, which
    would collide with an unrelated package of that name."""
    src = tmp_path / "src"
    ignore = shutil.ignore_patterns("__pycache__", "*.egg-info", "build")
    shutil.copytree(ROOT / "apcc_graph", src / "apcc_graph", symlinks=True, ignore=ignore)
    shutil.copytree(ROOT / "factors", src / "factors", ignore=ignore)
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, src / name)
    assert (src / "apcc_graph" / "factors").is_symlink()
    done = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w",
                           str(tmp_path / "dist"), str(src)],
                          capture_output=True, text=True, check=False)
    assert done.returncode == 0, done.stderr[-2000:]
    (wheel,) = (tmp_path / "dist").glob("apcc_graph-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    modules = {Path(n).stem for n in names if n.startswith("apcc_graph/factors/")}
    assert {"__init__", "projection", "camera_chain", "kinematic"} <= modules, names
    assert not [n for n in names if n.split("/")[0] == "factors"]
    # and the code imports it by that name only
    stray = [str(p.relative_to(ROOT)) for p in [*ROOT.glob("apcc_graph/**/*.py"),
                                                *ROOT.glob("factors/*.py"),
                                                *ROOT.glob("tests/*.py")]
             if re.search(r"^\s*(from|import) factors\b", p.read_text(), re.M)]
    assert stray == []
