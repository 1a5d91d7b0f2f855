"""The command line at its edges: the odd and bad inputs users have met, each run through the
installed ``apcc-graph`` in a subprocess (where a traceback could not hide) and judged.

Every case says what should happen: ``refused`` (exit 1, one line on stderr naming the thing),
``warned`` (exit 0, a warning line naming it) or ``accepted`` (exit 0, the output whole). A run
is then counted as

- a **traceback**: ``Traceback`` anywhere on stderr;
- a **silent accept**: a refused or warned case that exited 0 without the warning;
- **half-written**: a case that failed but left its output (or a staging folder) behind, or
  changed an output that was already there; an accepted case whose output is not whole;
- **wrong**: anything else unlike what the case expects (exit code, more than one line, the
  line not naming the thing).

``python tests/edge_matrix.py`` prints each case and the counts; ``tests/test_edge_matrix.py``
asserts every case. Needs the package installed (the ``apcc-graph`` beside this Python).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "data"
SAMPLE = DATA / "sequences" / "planar_three"
ROBOT = DATA / "robots" / "planar_three.toml"
CONSOLE = Path(sys.executable).parent / "apcc-graph"
THETA0 = "--theta0-deg=20.466,-15.210,21.277"
LONGEST_LINE = 600
"""Characters a one-line message may have, paths included (a refused huge file must not echo
its line)."""


def _sample_copy(w: Path) -> Path:
    """A copy of the shipped sample sequence, ``w/seq``."""
    shutil.copytree(SAMPLE, w / "seq")
    return w / "seq"


def _distorted(w: Path) -> None:
    seq = _sample_copy(w)
    text = (seq / "robot.toml").read_text()
    assert "distortion = []" in text
    (seq / "robot.toml").write_text(text.replace("distortion = []",
                                                 "distortion = [1e6, -1e6, 0, 0]", 1))


def _bom_frames(w: Path) -> None:
    seq = _sample_copy(w)
    (seq / "frames.csv").write_bytes(b"\xef\xbb\xbf" + (seq / "frames.csv").read_bytes())


def _utf16_frames(w: Path) -> None:
    seq = _sample_copy(w)
    (seq / "frames.csv").write_bytes((seq / "frames.csv").read_text().encode("utf-16"))


def _huge_tracks(w: Path) -> None:
    """cam_2's tracks a 2 GB file of one line (sparse: it takes no disk)."""
    seq = _sample_copy(w)
    with (seq / "tracks" / "cam_2.csv").open("r+b") as fh:
        fh.seek(0, os.SEEK_END)
        fh.truncate(2 * 1024**3)


def _few_tracks(w: Path) -> None:
    """cam_2 keeps only the rows of three tracks."""
    seq = _sample_copy(w)
    path = seq / "tracks" / "cam_2.csv"
    header, *rows = path.read_text().splitlines()
    ids = sorted({r.split(",")[1] for r in rows})[:3]
    assert header.split(",")[1] == "track_id"
    path.write_text("\n".join([header] + [r for r in rows if r.split(",")[1] in ids]) + "\n")


OFFSET_RAD = 0.01
"""What the estimates of the timestamp cases add to the true angles (0.573 deg)."""


def _theta_file(folder: Path, frames: list[int], dt: float) -> None:
    """A theta.csv of the sample's true angles plus :data:`OFFSET_RAD` at ``frames``, stamped
    every ``dt`` s."""
    truth = (SAMPLE / "frames.csv").read_text().splitlines()[1:]
    folder.mkdir()
    lines = ["frame,timestamp,theta_1,theta_2,theta_3,sigma_1,sigma_2,sigma_3"]
    for f in frames:
        angles = [repr(float(a) + OFFSET_RAD) for a in truth[f].split(",")[2:5]]
        lines.append(",".join([str(f), repr(f * dt), *angles, "0.001", "0.001", "0.001"]))
    (folder / "theta.csv").write_text("\n".join(lines) + "\n")


def _other_rate(w: Path) -> None:
    _theta_file(w / "est", list(range(200)), 1 / 60)  # the sample runs at 30 fps


def _gaps(w: Path) -> None:
    _theta_file(w / "est", [0, 1, 5, 6, 7, 40, 199], 1 / 30)


def _bom_robot(w: Path) -> None:
    (w / "robot.toml").write_bytes(b"\xef\xbb\xbf" + ROBOT.read_bytes())


def _mm_robot(w: Path) -> None:
    (w / "robot.toml").write_text(ROBOT.read_text().replace("length = 0.3", "length = 300"))


def _mm_calibration(w: Path) -> None:
    """The paper's calibration example written in millimetres (the length and the tip)."""
    lines = []
    for line in (DATA / "calibration" / "paper_example.toml").read_text().splitlines():
        key, _, value = line.partition(" = ")
        if key in ("length", "tip_x", "tip_z"):
            line = f"{key} = {1000 * float(value)!r}"
        lines.append(line)
    assert sum(" = " in x and x.split(" = ")[0] in ("length", "tip_x", "tip_z")
               for x in lines) == 3
    (w / "cal.toml").write_text("\n".join(lines) + "\n")


def _xyzw_poses(w: Path) -> None:
    """The real robot's backbone poses, quaternions written x, y, z, w."""
    lines = (DATA / "real_tdcr" / "impulse_2" / "backbone_poses.csv").read_text().splitlines()
    assert lines[0] == "timestamp,arclength,x,y,z,qw,qx,qy,qz"
    swapped = [lines[0]] + [",".join(f[:5] + [f[6], f[7], f[8], f[5]])
                            for f in (line.split(",") for line in lines[1:])]
    (w / "poses.csv").write_text("\n".join(swapped) + "\n")


def _not_empty(w: Path) -> None:
    (w / "full").mkdir()
    (w / "full" / "mine.txt").write_text("keep me\n")


def _header_only(w: Path) -> None:
    """An estimate folder whose theta.csv has a header of one column and no rows."""
    (w / "full").mkdir()
    (w / "full" / "theta.csv").write_text("frame\n")


def _a_file(w: Path) -> None:
    (w / "file").write_text("x\n")


def _rows(path: Path, n: int) -> str | None:
    """``None`` when ``path`` is a CSV of ``n`` rows after its header, else what is wrong."""
    if not path.is_file():
        return f"{path.name} missing"
    rows = len(path.read_text().splitlines()) - 1
    return None if rows == n else f"{path.name} has {rows} rows, expected {n}"


def _matched_by_frame(w: Path, stdout: str) -> str | None:
    """``evaluate`` of the estimate with gaps: its 7 rows compared with their own frames (every
    error then the offset; compared by position they would not be)."""
    rms = next((line.split()[2:] for line in stdout.splitlines() if line.startswith("RMS (deg)")),
               None)
    if "compared on the 7 frames the estimate has, of the truth's 200" not in stdout:
        return "no coverage line"
    if rms != ["0.5730"] * 3:
        return f"RMS {rms}, expected 0.5730 deg each (the rows' own frames)"
    return None


def _estimate_whole(w: Path, stdout: str) -> str | None:
    for name in ("theta.csv", "tips_seg_1.tum", "tips_seg_2.tum", "tips_seg_3.tum"):
        problem = _rows(w / "e" / name, 200 if name == "theta.csv" else 199)
        if problem:
            return problem
    return None


@dataclass(frozen=True)
class Case:
    """One input at the edge: the command (``{w}`` is the case's own folder, ``{sample}`` the
    shipped sample, ``{robot}`` its robot, ``{data}`` the data folder), what should happen,
    what the message must contain, the output the command would write, how to make the
    case's files, and, for accepted cases, a check of the output given the case's folder and
    what the command printed (``None`` when whole)."""

    name: str
    argv: tuple[str, ...]
    expect: str
    needle: str = ""
    out: str | None = None
    make: Callable[[Path], None] | None = None
    check: Callable[[Path, str], str | None] | None = field(default=None, compare=False)


EST = ("estimate", "{sample}", "--method", "chain", THETA0)
"""The chain on the shipped sample (cases add their options and ``--out``)."""
COPY = ("estimate", "{w}/seq", "--method", "chain", THETA0, "--out", "{w}/e")
"""The chain on the case's copy of the sample, into ``{w}/e``."""
CASES: tuple[Case, ...] = (
    Case("camera distortion [1e6,-1e6,0,0], smoother",
         ("estimate", "{w}/seq", "--method", "smoother", THETA0, "--out", "{w}/e"),
         "refused", "distortion", "{w}/e", _distorted),
    Case("camera distortion [1e6,-1e6,0,0], chain", COPY, "refused", "distortion", "{w}/e",
         _distorted),
    Case("UTF-8 byte-order mark in frames.csv", COPY, "accepted", out="{w}/e",
         make=_bom_frames, check=_estimate_whole),
    Case("UTF-16 frames.csv", COPY, "refused", "UTF-16", "{w}/e", _utf16_frames),
    Case("a 2 GB one-line tracks file", COPY, "refused", "cam_2.csv", "{w}/e", _huge_tracks),
    Case("a camera with three tracks", COPY, "warned", "cam_2", "{w}/e", _few_tracks),
    Case("--noise-px nan", (*EST, "--noise-px", "nan", "--out", "{w}/e"),
         "refused", "--noise-px", "{w}/e"),
    Case("--noise-px -1", (*EST, "--noise-px", "-1", "--out", "{w}/e"),
         "refused", "--noise-px", "{w}/e"),
    Case("--theta0-deg beyond theta_max",
         ("estimate", "{sample}", "--theta0-deg=95,0,0", "--out", "{w}/e"),
         "refused", "theta_max", "{w}/e"),
    Case("--out is a file", (*EST, "--out", "{w}/file"), "refused", "is a file", "{w}/file",
         _a_file),
    Case("--out is a file, with --force", (*EST, "--out", "{w}/file", "--force"), "refused",
         "is a file", "{w}/file", _a_file),
    Case("--out under a file", (*EST, "--out", "{w}/file/e"), "refused", "file",
         "{w}/file/e", _a_file),
    Case("--out not writable", (*EST, "--out", "/proc/self/e"), "refused", "/proc/self"),
    Case("--out not empty, no --force", (*EST, "--out", "{w}/full"), "refused", "--force",
         "{w}/full", _not_empty),
    Case("--out holds the input, with --force",
         ("estimate", "{w}/seq", "--method", "chain", THETA0, "--out", "{w}/seq", "--force"),
         "refused", "--out", "{w}/seq", _sample_copy),
    Case("track --sync-tolerance -1",
         ("track", "--video", "a.mp4,b.mp4,c.mp4", "--robot", "{robot}", "--out", "{w}/t",
          "--sync-tolerance", "-1"), "refused", "--sync-tolerance", "{w}/t"),
    Case("live --sync-tolerance -1",
         ("live", "--video", "a.mp4,b.mp4,c.mp4", "--robot", "{robot}", "--out", "{w}/l",
          "--sync-tolerance", "-1"), "refused", "--sync-tolerance", "{w}/l"),
    Case("live from a source that does not exist",
         ("live", "{w}/nothing", "--robot", "{robot}", "--out", "{w}/l"),
         "refused", "nothing", "{w}/l"),
    Case("evaluate against a truth at another frame rate",
         ("evaluate", "{w}/est", "--truth", "{sample}"), "refused", "frame rate", None,
         _other_rate),
    Case("plot against a truth at another frame rate",
         ("plot", "{w}/est", "--truth", "{sample}", "--output", "{w}/f.png"),
         "refused", "frame rate", "{w}/f.png", _other_rate),
    Case("evaluate an estimate with skipped frames",
         ("evaluate", "{w}/est", "--truth", "{sample}"), "accepted", make=_gaps,
         check=_matched_by_frame),
    Case("plot an estimate with skipped frames",
         ("plot", "{w}/est", "--truth", "{sample}", "--output", "{w}/f.png"), "accepted",
         out="{w}/f.png", make=_gaps,
         check=lambda w, _: None if (w / "f.png").stat().st_size > 1000 else "empty figure"),
    Case("robot.toml with a byte-order mark",
         ("simulate", "--robot", "{w}/robot.toml", "--frames", "3", "--out", "{w}/s"),
         "accepted", out="{w}/s", make=_bom_robot,
         check=lambda w, _: _rows(w / "s" / "frames.csv", 3)),
    Case("robot.toml in millimetres",
         ("simulate", "--robot", "{w}/robot.toml", "--frames", "3", "--out", "{w}/s"),
         "warned", "length", "{w}/s", _mm_robot),
    Case("calibration file in millimetres", ("calibrate", "{w}/cal.toml"), "warned",
         "length", None, _mm_calibration),
    Case("backbone quaternions written x, y, z, w",
         ("calibrate", "{w}/poses.csv", "--robot", "{data}/robots/real_tdcr.toml",
          "--output", "{w}/real.toml"), "warned", "x, y, z, w", "{w}/real.toml", _xyzw_poses),
    Case("plot a malformed theta.csv",
         ("plot", "{w}/full", "--output", "{w}/f.png"), "refused", "theta.csv", "{w}/f.png",
         _header_only),
    Case("evaluate a folder that does not exist",
         ("evaluate", "{w}/nothing", "--truth", "{sample}"), "refused", "nothing"),
    Case("simulate --out is a file",
         ("simulate", "--robot", "{robot}", "--frames", "2", "--out", "{w}/file"),
         "refused", "is a file", "{w}/file", _a_file),
    Case("montecarlo --out under a file",
         ("montecarlo", "--runs", "1", "--frames", "5", "--out", "{w}/file/mc"),
         "refused", "file", "{w}/file/mc", _a_file),
    Case("calibrate --output under a file",
         ("calibrate", "{data}/calibration/paper_example.toml", "--output",
          "{w}/file/robot.toml"), "refused", "file", "{w}/file/robot.toml", _a_file),
)
"""Every case, in the order they are reported."""


@dataclass
class Outcome:
    """What one case did and the problems found (empty when it behaved as expected)."""

    case: Case
    returncode: int
    stderr: str
    problems: list[str]


def _snapshot(path: Path) -> dict[str, tuple[int, int] | None] | None:
    """Every file and folder under ``path`` (``path`` included) with its size and modification
    time (``None`` for a folder); ``None`` if ``path`` is absent. Sizes and times, not bytes:
    a case's input may be a 2 GB file."""
    if not path.exists():
        return None
    found = {}
    for p in [path, *sorted(path.rglob("*"))] if path.is_dir() else [path]:
        st = p.stat()
        found[str(p.relative_to(path))] = None if p.is_dir() else (st.st_size, st.st_mtime_ns)
    return found


def run_case(case: Case, work: Path, timeout: float = 600) -> Outcome:
    """Make ``case``'s files in the empty folder ``work``, run it through the console and judge
    it."""
    if case.make:
        case.make(work)
    fill = {"w": str(work), "sample": str(SAMPLE), "robot": str(ROBOT), "data": str(DATA)}
    argv = [a.format(**fill) for a in case.argv]
    out = Path(case.out.format(**fill)) if case.out else None
    before = _snapshot(work)
    existed = out is not None and out.exists()
    env = {**os.environ, "COLUMNS": "200"}
    done = subprocess.run([str(CONSOLE), *argv], capture_output=True, text=True,
                          timeout=timeout, env=env, cwd=work)
    lines = done.stderr.strip().splitlines()
    problems: list[str] = []
    if "Traceback" in done.stderr:
        problems.append("traceback")
    named = [line for line in lines if case.needle in line]
    if case.expect in ("refused", "warned") and done.returncode == 0 and not (
            case.expect == "warned" and any("warning:" in line for line in named)):
        problems.append("silent accept")
    if case.expect == "refused" or done.returncode != 0:
        # nothing written, nothing of the user's changed (also where --out is outside work)
        if _snapshot(work) != before or (out is not None and not existed and out.exists()):
            problems.append("half-written")
    elif case.check and (problem := case.check(work, done.stdout)):
        problems.append(f"half-written: {problem}")
    if case.expect == "refused":
        if done.returncode != 1 or len(lines) != 1 or not named:
            problems.append(f"wrong: exit {done.returncode}, {len(lines)} lines on stderr")
        elif len(lines[0]) > LONGEST_LINE:
            problems.append(f"wrong: a line of {len(lines[0])} characters")
    elif case.expect == "warned":
        if done.returncode != 0 or not any("warning:" in line for line in named):
            problems.append(f"wrong: exit {done.returncode}, no warning naming {case.needle!r}")
    elif done.returncode != 0:
        problems.append(f"wrong: exit {done.returncode}")
    return Outcome(case, done.returncode, done.stderr, problems)


KINDS = ("traceback", "silent accept", "half-written", "wrong")


def main() -> int:
    """Run every case and print one line each, then the counts; exit 1 if any case failed."""
    counts = dict.fromkeys(KINDS, 0)
    expected = {"refused": 0, "warned": 0, "accepted": 0}
    for case in CASES:
        with tempfile.TemporaryDirectory() as tmp:
            outcome = run_case(case, Path(tmp))
        expected[case.expect] += 1
        for kind in KINDS:
            counts[kind] += any(p.startswith(kind) for p in outcome.problems)
        verdict = "; ".join(outcome.problems) or "ok"
        line = outcome.stderr.strip().splitlines()
        shown = (line[0] if case.expect == "refused" else next(
            (x for x in line if "warning:" in x), "")) if line else ""
        print(f"{case.name:48s} {case.expect:9s} exit {outcome.returncode:3d}  {verdict}"
              + (f"\n    {shown[:150]}" if shown else ""), flush=True)
    print(f"\n{len(CASES)} cases ({expected['refused']} refused, {expected['warned']} warned, "
          f"{expected['accepted']} accepted): " + ", ".join(f"{counts[k]} {k}" for k in KINDS))
    return int(any(counts.values()))


if __name__ == "__main__":
    sys.exit(main())
