"""Ctrl-C and failures: an interrupted command says so in one line and exits with 130, leaving
nothing half-written (a run over many sequences keeps the ones it finished); a gtsam failure is
one line naming the variable it concerns; any other failure is one line, never a traceback
(``--debug`` shows it). The CLI matrix's mistakes run through the installed ``apcc-graph`` in
a subprocess, where a traceback could not hide (the odd inputs users met: tests/edge_matrix.py)."""

from __future__ import annotations

import ctypes
import math
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import gtsam
import numpy as np
import pytest

from apcc_graph.cli import main
from apcc_graph.io import load_robot, save_sequence
from apcc_graph.io.interrupts import catching_interrupts
from apcc_graph.simulation.simulator import simulate

REPO = Path(__file__).resolve().parents[1]
ROBOT = REPO / "data" / "robots" / "planar_three.toml"
SAMPLE = REPO / "data" / "sequences" / "planar_three"
CONSOLE = Path(sys.executable).parent / "apcc-graph"


@pytest.fixture(autouse=True)
def _ctrl_c_as_on_a_terminal() -> Iterator[None]:
    """Ctrl-C reaches this process and its subprocesses as from a terminal: a suite started in
    the background by a non-interactive shell (``pytest &``) inherits SIGINT ignored, and a
    subprocess would inherit that too and never see the signal these tests send. A handler
    (unlike an ignore) is reset to the default when a subprocess starts."""
    before = signal.getsignal(signal.SIGINT)
    if before is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, before)


@pytest.fixture(scope="module")
def short(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    """A 12-frame simulated sequence and its true start as ``--theta0-deg``."""
    folder = tmp_path_factory.mktemp("short") / "seq_12"
    sim = simulate(load_robot(ROBOT), 12, noise_px=0.5, seed=12)
    save_sequence(sim.sequence, folder)
    return folder, "--theta0-deg=" + ",".join(f"{math.degrees(t):.4f}"
                                              for t in sim.sequence.thetas[0])


def _loaded(pid: int, library: str) -> bool:
    """Whether process ``pid`` has mapped a shared library whose name holds ``library``."""
    try:
        return library in Path(f"/proc/{pid}/maps").read_text()
    except OSError:
        return False


def _copies(folder: Path, names: tuple[str, ...], into: Path) -> Path:
    """``into/<name>/``: a copy of the sequence ``folder`` for each name; returns ``into``."""
    for name in names:
        target = into / name
        (target / "tracks").mkdir(parents=True)
        for item in [*folder.glob("*.*"), *(folder / "tracks").iterdir()]:
            (target / item.relative_to(folder)).write_bytes(item.read_bytes())
    return into


def _wait_for(proc: subprocess.Popen, ready: Callable[[], bool], what: str,
              timeout: float = 180.0) -> None:
    """Poll until ``ready()`` (a marker of how far the command got), then check that the
    command still runs (with nothing but generous timeouts: the machine's speed varies)."""
    deadline = time.monotonic() + timeout
    while not ready():
        assert proc.poll() is None, f"the command ended before {what}: {proc.stderr.read()}"
        assert time.monotonic() < deadline, f"never {what}"
        time.sleep(0.005)
    assert proc.poll() is None, f"the command ended just as {what}"


@pytest.mark.parametrize("marker", ["gtsam", "llvmlite", "done.txt"])
def test_sigint_to_a_batch_estimate_exits_130_in_one_line_and_writes_nothing(
        marker: str, short, tmp_path: Path) -> None:
    # once gtsam was loaded, python -m was killed by SIGINT after printing the line (CPython's
    # note of a KeyboardInterrupt that passed through an extension's PyRun_String); once numba
    # was loaded, or a first sequence was done, inside numba's compiled code, it surfaced as
    # "SystemError: CPUDispatcher(...) returned a result with an exception set"
    out = tmp_path / "est"
    names = ("a", "b", "c", "d", "e", "f")
    source = (str(_copies(short[0], names, tmp_path / "seqs")) if marker == "done.txt"
              else str(SAMPLE))
    command = [sys.executable, "-m", "apcc_graph.cli", "estimate", source, "--method", "batch",
               "--out", str(out), *(["--workers", "1", short[1]] if marker == "done.txt" else [])]
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    if marker == "done.txt":  # the second sequence is being estimated
        _wait_for(proc, lambda: (out / "a" / "done.txt").is_file(), "a sequence was done")
    else:
        _wait_for(proc, lambda: _loaded(proc.pid, marker), f"{marker} was loaded")
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130, stderr
    assert stderr.strip().splitlines() == ["apcc-graph: interrupted"]
    assert stdout == ""
    if marker == "done.txt":  # the finished sequences whole, nothing of the others
        kept = sorted(p.name for p in out.iterdir())
        assert "a" in kept and len(kept) < len(names), kept
        assert all((out / name / "done.txt").is_file() for name in kept)
        assert not list(tmp_path.glob(".*"))
    else:
        assert list(tmp_path.iterdir()) == []  # no output folder, no staging folder


def test_sigint_between_loading_and_main_is_one_line_too() -> None:
    # the command's modules are loaded, main() has not yet taken Ctrl-C over
    code = ("import signal, sys; sys.argv[0] = 'apcc-graph'; from apcc_graph.cli import main; "
            "signal.raise_signal(signal.SIGINT); sys.exit(main(['--help']))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 130, proc.stderr
    assert proc.stderr.strip().splitlines() == ["apcc-graph: interrupted"]
    assert proc.stdout == ""  # main acted on it before doing anything
    # a program that imports the command line keeps Python's own Ctrl-C
    code = ("import signal, apcc_graph.cli; "
            "assert signal.getsignal(signal.SIGINT) is signal.default_int_handler")
    assert subprocess.run([sys.executable, "-c", code], timeout=120).returncode == 0


def test_sigint_while_the_command_loads_is_one_line_too(tmp_path: Path) -> None:
    out = tmp_path / "est"
    proc = subprocess.Popen([str(CONSOLE), "estimate", str(SAMPLE), "--out", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while not _loaded(proc.pid, "cv2") and proc.poll() is None:  # apcc_graph.cli loading
        assert time.monotonic() < deadline
        time.sleep(0.005)
    proc.send_signal(signal.SIGINT)
    _, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130
    assert stderr.strip().splitlines() == ["apcc-graph: interrupted"]
    assert list(tmp_path.iterdir()) == []


def test_an_interrupted_many_sequence_run_keeps_the_finished_ones(
        short, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    import apcc_graph.estimation.methods as methods

    folder, theta0 = short
    seqs = tmp_path / "seqs"
    for name in ("a", "b", "c"):
        (seqs / name).mkdir(parents=True)
        for item in folder.rglob("*"):
            target = seqs / name / item.relative_to(folder)
            if item.is_dir():
                target.mkdir(exist_ok=True)
            else:
                target.write_bytes(item.read_bytes())
    real, calls = methods.estimate, []

    def estimate(sequence, **kwargs):  # noqa: ANN001, ANN003, ANN202
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt  # Ctrl-C while the second sequence is estimated
        return real(sequence, **kwargs)

    monkeypatch.setattr(methods, "estimate", estimate)
    out = tmp_path / "out"
    assert main(["estimate", str(seqs), "--method", "chain", "--workers", "1", "--out",
                 str(out), theta0]) == 130
    assert capsys.readouterr().err.strip().splitlines()[-1] == "apcc-graph: interrupted"
    assert sorted(p.name for p in out.iterdir()) == ["a"]  # b: nothing, not even staging
    assert sorted(p.name for p in (out / "a").iterdir()) == [
        "done.txt", "theta.csv", "tips_seg_1.tum", "tips_seg_2.tum", "tips_seg_3.tum"]

    monkeypatch.setattr(methods, "estimate", real)  # the re-run reads "a" back
    assert main(["estimate", str(seqs), "--method", "chain", "--workers", "1", "--out",
                 str(out), theta0]) == 0
    assert "2 estimated, 1 already complete, 0 failed" in capsys.readouterr().out


def test_ctrl_c_at_a_terminal_stops_a_dask_cluster_in_one_line(tmp_path: Path) -> None:
    pytest.importorskip("distributed")
    import psutil

    seqs = _copies(SAMPLE, ("a", "b", "c", "d"), tmp_path / "seqs")
    out = tmp_path / "out"
    proc = subprocess.Popen([str(CONSOLE), "estimate", str(seqs), "--method", "batch",
                             "--workers", "2", "--out", str(out)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    deadline = time.monotonic() + 180
    while proc.poll() is None:  # both workers estimating (gtsam loaded)
        assert time.monotonic() < deadline, "the cluster never started"
        workers = [c.pid for c in psutil.Process(proc.pid).children(recursive=True)
                   if "spawn" in " ".join(c.cmdline())]
        if len([pid for pid in workers if _loaded(pid, "gtsam")]) >= 2:
            break
        time.sleep(0.2)
    # a first sequence done: the workers are estimating (without their preload, their
    # tracebacks showed from here on)
    _wait_for(proc, lambda: any(out.glob("*/done.txt")), "a sequence was done")
    os.killpg(proc.pid, signal.SIGINT)  # as Ctrl-C at a terminal: every process of the group
    _, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130, stderr
    assert stderr.strip().splitlines() == ["apcc-graph: interrupted"]
    assert not list(tmp_path.glob("out/.*")) and not list(tmp_path.glob(".*"))


def test_an_interrupted_run_that_finished_nothing_leaves_no_out(
        short, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    def estimate(*args: object, **kwargs: object) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr("apcc_graph.estimation.methods.estimate", estimate)
    folder, theta0 = short
    assert main(["estimate", str(folder.parent), "--method", "chain",  # a folder of one
                 "--workers", "1", "--out", str(tmp_path / "out"), theta0]) == 130
    assert list(tmp_path.iterdir()) == []
    assert main(["estimate", str(folder), "--method", "chain", "--out",
                 str(tmp_path / "one"), theta0]) == 130
    assert list(tmp_path.iterdir()) == []
    assert capsys.readouterr().err.strip().splitlines() == ["apcc-graph: interrupted"] * 2


def test_a_ctrl_c_swallowed_by_a_c_callback_is_raised_again() -> None:
    # numba compiles through ctypes callbacks: a KeyboardInterrupt raised inside one is
    # printed as "Exception ignored" and lost, and the command went on to the end
    callback = ctypes.CFUNCTYPE(None)(lambda: signal.raise_signal(signal.SIGINT))
    with pytest.raises(KeyboardInterrupt), catching_interrupts():  # noqa: PT012
        callback()
        for _ in range(1000):  # the signal arrives at the next line of Python
            time.sleep(0.001)
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


@pytest.mark.parametrize("many", [False, True])
def test_ctrl_c_that_surfaces_as_another_error_is_still_an_interruption(
        many: bool, short, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    # Ctrl-C while numba's compiled code runs came out as "SystemError: CPUDispatcher(...)
    # returned a result with an exception set" and was printed as an internal error
    calls = []

    def estimate(*args: object, **kwargs: object) -> None:
        calls.append(1)
        try:
            signal.raise_signal(signal.SIGINT)
            time.sleep(0.01)
        except KeyboardInterrupt:
            pass  # swallowed, as compiled code does
        raise SystemError("CPUDispatcher(<function reduced>) returned a result with an "
                          "exception set")

    monkeypatch.setattr("apcc_graph.estimation.methods.estimate", estimate)
    folder, theta0 = short
    seqs, more = [str(folder)], []
    if many:  # two sequences: the second must not be started
        more = ["--workers", "1"]
        other = tmp_path / "other" / "seq_b"
        other.mkdir(parents=True)
        for item in folder.rglob("*"):
            target = other / item.relative_to(folder)
            target.mkdir() if item.is_dir() else target.write_bytes(item.read_bytes())
        seqs = [str(folder), str(other)]
    assert main(["estimate", *seqs, "--method", "chain", "--out", str(tmp_path / "out"),
                 theta0, *more]) == 130
    assert capsys.readouterr().err.strip().splitlines() == ["apcc-graph: interrupted"]
    assert len(calls) == 1
    assert not (tmp_path / "out").exists()


def _indeterminate_gtsam_error() -> RuntimeError:
    """gtsam's own error for frame 42's vector left free (a graph without a prior)."""
    graph = gtsam.NonlinearFactorGraph()
    x42, x43 = gtsam.symbol("x", 42), gtsam.symbol("x", 43)
    graph.add(gtsam.BetweenFactorVector(x42, x43, np.ones(3),
                                        gtsam.noiseModel.Isotropic.Sigma(3, 1.0)))
    values = gtsam.Values()
    values.insert(x42, np.zeros(3))
    values.insert(x43, np.zeros(3))
    with pytest.raises(RuntimeError) as caught:
        gtsam.GaussNewtonOptimizer(graph, values).optimize()
    return caught.value


@pytest.fixture
def failing_gtsam(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every estimate fails with a real gtsam error (an indeterminate system near frame 42)."""
    error = _indeterminate_gtsam_error()

    def estimate(*args: object, **kwargs: object) -> None:
        raise error

    monkeypatch.setattr("apcc_graph.estimation.methods.estimate", estimate)


def test_a_gtsam_failure_is_one_line_naming_the_frame(short, tmp_path: Path, failing_gtsam,
                                                      capsys) -> None:
    folder, theta0 = short
    assert main(["estimate", str(folder), "--method", "smoother", "--out",
                 str(tmp_path / "est"), theta0]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith("apcc-graph: error: gtsam failed near frame 42's bends: an "
                             "indeterminate linear system")
    assert "--factorization QR" in err[0] and "8646911284551352362" not in err[0]
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(RuntimeError):  # --debug shows gtsam's own
        main(["--debug", "estimate", str(folder), "--method", "smoother", "--out",
              str(tmp_path / "est"), theta0])


def test_a_gtsam_failure_in_a_many_sequence_run_is_that_sequence_s_status(
        short, tmp_path: Path, failing_gtsam, capsys) -> None:
    folder, theta0 = short
    assert main(["estimate", str(folder.parent), "--workers", "1", "--out",
                 str(tmp_path / "out"), theta0]) == 0
    assert "failed: gtsam failed near frame 42's bends" in capsys.readouterr().out


def test_an_unexpected_error_is_one_line_and_debug_shows_its_traceback(
        short, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    def estimate(*args: object, **kwargs: object) -> None:
        raise KeyError("segment_9")

    monkeypatch.setattr("apcc_graph.estimation.methods.estimate", estimate)
    folder, theta0 = short
    argv = ["estimate", str(folder), "--out", str(tmp_path / "est"), theta0]
    assert main(argv) == 1
    assert capsys.readouterr().err.strip().splitlines() == [
        "apcc-graph: error: internal error: KeyError: 'segment_9' (run with --debug for the "
        "traceback)"]
    with pytest.raises(KeyError):
        main(["--debug", *argv])


def _matrix_mistakes() -> list[tuple[list[str], str]]:
    """The mistakes matrix of tests/test_cli_matrix.py (its parameters)."""
    import test_cli_matrix as matrix

    marks = matrix.test_user_mistakes_end_in_one_line_and_exit_1.pytestmark
    return next(m for m in marks if m.name == "parametrize").args[1]


@pytest.fixture(scope="module")
def estimate_dir(short, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("matrix") / "est"
    folder, theta0 = short
    assert main(["estimate", str(folder), "--method", "chain", "--out", str(out), theta0]) == 0
    return out


@pytest.mark.parametrize("argv, expected", _matrix_mistakes())
def test_the_cli_matrix_s_mistakes_through_the_console(argv: list[str], expected: str,
                                                       estimate_dir: Path,
                                                       tmp_path: Path) -> None:
    args = [a.format(tmp=tmp_path, est=estimate_dir) for a in argv]
    done = subprocess.run([str(CONSOLE), *args], capture_output=True, text=True, timeout=300)
    assert "Traceback" not in done.stderr
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 1 and len(lines) == 1 and expected in lines[0], done.stderr
