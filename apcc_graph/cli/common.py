"""What the subcommands of ``apcc-graph`` share: the user-error type, the one-line-error parser,
number types for options, the parent parsers of options that mean the same thing in every
command (``--seed``, ``--seeds``, ``--out``/``--output``, ``--force``, ``--robot``, ``--frames``,
and an estimate folder with its ``--truth``), the rule for output files and folders, and the
readers of comma-separated lists (degrees, integers).

A subcommand module turns parsed arguments into a call of a library function that returns a
result object, and formats that result as text. User mistakes (a missing or malformed file, a
bad value) end in one line on stderr and exit code 1; ``--debug`` shows the traceback instead.
"""

from __future__ import annotations

import argparse
import math
import re
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NoReturn

import numpy as np

FORMATTER = argparse.RawDescriptionHelpFormatter
"""Help formatter of every subcommand: keeps the examples' line breaks."""


class UserError(Exception):
    """A mistake in what the user asked for; printed as one line, exit code 1."""


NEGATIVE = re.compile(r"^-\d+$|^-\d*\.\d+$|^-\d*\.?\d[^,]*(,[^,]*)+$")
"""What a value that starts with a minus sign looks like: a negative number, or a
comma-separated list whose first value is negative (``--theta0-deg -15,3,4``). No option of
``apcc-graph`` looks like that, so the parser reads it as the option's value."""


class Parser(argparse.ArgumentParser):
    """An argument parser whose usage errors are one line on stderr and exit code 1, and that
    takes a list of numbers starting with a negative one as a value (:data:`NEGATIVE`)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        # argparse decides with this pattern whether "-15,3,4" is a value or an unknown option
        self._negative_number_matcher = NEGATIVE

    def error(self, message: str) -> NoReturn:
        """Print ``message`` as one line with a pointer to ``--help`` and exit with code 1."""
        self.exit(1, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _number_type(check: Callable[[float], bool], what: str,
                 cast: Callable[[str], float] = float) -> Callable[[str], float]:
    def parse(text: str) -> float:
        """``text`` as a number of the option's kind and range, else a usage error."""
        try:
            value = cast(text)
        except ValueError:
            kind = "an integer" if cast is int else "a number"
            raise argparse.ArgumentTypeError(f"{text!r} is not {kind}") from None
        if not (math.isfinite(value) and check(value)):
            raise argparse.ArgumentTypeError(f"{text!r}: expected {what}")
        return value

    return parse


positive = _number_type(lambda v: v > 0, "a number > 0")
non_negative = _number_type(lambda v: v >= 0, "a number >= 0")
fraction = _number_type(lambda v: 0 <= v < 1, "a fraction 0 <= p < 1")


def model_sigma(text: str) -> tuple[float, float]:
    """An option type: ``MM,DEG`` (a model noise) as ``(metres, radians)``, both > 0."""
    try:
        mm, deg = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected two numbers MM,DEG, e.g. 1,0.5"
                                         ) from None
    if not all(math.isfinite(v) and v > 0.0 for v in (mm, deg)):
        raise argparse.ArgumentTypeError(f"{text!r}: expected positive millimetres and degrees")
    return mm * 1e-3, math.radians(deg)


def add_model_options(parser: argparse.ArgumentParser) -> None:
    """``--model-sigma MM,DEG`` and ``--exact-model``, one or neither: the measurement model of
    the batch and the smoother (by default the robot file's model error)."""
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--model-sigma", type=model_sigma, default=None, metavar="MM,DEG",
                       help="model error as noise for every segment: how far a segment's tip "
                       "may depart from its kinematic model, position in mm and rotation in "
                       "degrees, e.g. 1,0.5 (default: each segment's model_error in the robot "
                       "file, which apcc-graph calibrate writes; the exact model where the "
                       "file has none); docs/estimation.md")
    group.add_argument("--exact-model", action="store_true",
                       help="the exact model, whatever model error the robot file gives")


def chosen_model_sigma(args: argparse.Namespace) -> object:
    """``GraphOptions.model_sigma`` of :func:`add_model_options`' flags."""
    if getattr(args, "exact_model", False):
        return None
    return "robot" if args.model_sigma is None else args.model_sigma


def at_least(minimum: int) -> Callable[[str], float]:
    """An option type: an integer of at least ``minimum``."""
    return _number_type(lambda v: v >= minimum, f"an integer >= {minimum}", int)


def seed_option(default: int | None = 0, help: str | None = None) -> argparse.ArgumentParser:  # noqa: A002
    """Parent parser of ``--seed``: the random seed of whatever the command simulates."""
    parent = argparse.ArgumentParser(add_help=False)
    parent.add_argument("--seed", type=int, default=default,
                        help=help or f"random seed (default {default})")
    return parent


def seeds_option(default: str) -> argparse.ArgumentParser:
    """Parent parser of ``--seeds``: comma-separated simulation seeds (read by
    :func:`int_list`)."""
    parent = argparse.ArgumentParser(add_help=False)
    parent.add_argument("--seeds", default=default,
                        help="simulation seeds, comma-separated (default: %(default)s)")
    return parent


def out_option(help: str, required: bool = True,  # noqa: A002
               metavar: str | None = None) -> argparse.ArgumentParser:
    """Parent parser of the output path, ``--out`` or its synonym ``--output`` (``args.out``)."""
    parent = argparse.ArgumentParser(add_help=False)
    parent.add_argument("--out", "--output", dest="out", required=required, metavar=metavar,
                        help=help)
    return parent


def add_dask_options(group: argparse._ActionsContainer) -> None:
    """``--workers`` and ``--scheduler``: where many recordings run (a local Dask cluster, this
    process, or an existing cluster)."""
    group.add_argument("--workers", type=at_least(1), default=None,
                       help="Dask workers on a local cluster (default: one per core; 1 runs in "
                       "this process; Dask is the [dask] extra)")
    group.add_argument("--scheduler", metavar="ADDRESS", default=None,
                       help="run on an existing dask.distributed cluster instead")


def force_option(help: str) -> argparse.ArgumentParser:  # noqa: A002
    """Parent parser of ``--force``: write where something already is."""
    parent = argparse.ArgumentParser(add_help=False)
    parent.add_argument("--force", action="store_true", help=help)
    return parent


def robot_option(default: str | None = None, shown: str | None = None
                 ) -> argparse.ArgumentParser:
    """Parent parser of ``--robot``: a robot.toml file, required unless ``default`` is given
    (``shown``: how the help names the default, if not by its path)."""
    parent = argparse.ArgumentParser(add_help=False)
    told = "" if default is None else f" (default: {shown or '%(default)s'})"
    parent.add_argument("--robot", required=default is None, default=default,
                        help="robot.toml" + told)
    return parent


def bench_robot_option() -> argparse.ArgumentParser:
    """``--robot``, by default the benches' three-segment robot shipped with the package."""
    from apcc_graph.bench import ROBOT_FILE

    return robot_option(str(ROBOT_FILE), "the three-segment robot shipped with apcc_graph, "
                        "as data/robots/planar_three.toml")


def frames_option(default: int | None = None, minimum: int | None = 1,
                  help: str | None = None) -> argparse.ArgumentParser:  # noqa: A002
    """Parent parser of ``--frames``: how many frames the command simulates or times; required
    unless ``default`` is given. ``minimum=None`` leaves the range check to the command."""
    parent = argparse.ArgumentParser(add_help=False)
    parent.add_argument("--frames", type=int if minimum is None else at_least(minimum),
                        required=default is None, default=default,
                        help=help or ("number of frames" if default is None
                                      else "frames (default: %(default)s)"))
    return parent


def estimate_option(truth_required: bool) -> argparse.ArgumentParser:
    """Parent parser of an estimate folder to read (the ``--out`` of ``estimate``) and the
    ``--truth`` sequence to compare it with."""
    parent = argparse.ArgumentParser(add_help=False)
    parent.add_argument("estimate", help="folder with theta.csv (the --out of estimate)")
    parent.add_argument("--truth", required=truth_required,
                        help="sequence folder with ground truth")
    return parent


def check_output_folder(path: str | Path, force: bool,
                        inputs: Sequence[str | Path] = ()) -> Path:
    """The output folder of a command: new or empty, or anything with ``--force`` (the one rule
    of every command that writes a folder), and writable; checked before any computing. With
    ``--force`` it is replaced whole when the new output is complete, so it must not be (or
    hold) one of the command's ``inputs``."""
    from apcc_graph.io.output_folder import check_writable, replace_refusal

    out = Path(path)
    if out.exists() and not out.is_dir():
        raise UserError(f"{out}: is a file, expected a folder to write into; choose another "
                        "--out")
    if out.exists() and any(out.iterdir()) and not force:
        raise UserError(f"{out}: exists and is not empty; choose another --out or add --force")
    refusal = replace_refusal(out, inputs) if out.exists() and force else None
    if refusal is not None:
        raise UserError(f"{out}: {refusal}: choose another --out")
    check_writable(out, folder=True)
    return out


def check_output_file(path: str | Path, force: bool) -> Path:
    """An output file of a command: new, or replaced with ``--force`` (the rule of
    :func:`check_output_folder`, for a file), and writable."""
    from apcc_graph.io.output_folder import check_writable

    out = Path(path)
    if out.exists() and not force:
        raise UserError(f"{out}: exists; choose another path or add --force to replace it")
    check_writable(out, folder=False)
    return out


def deg(radians: float) -> str:
    """An angle for a table: degrees with three decimals, ``-`` for NaN."""
    return "-" if math.isnan(radians) else f"{math.degrees(radians):.3f} deg"


def degree_list(text: str, option: str, hint: str = "") -> list[float]:
    """Comma-separated degrees of ``option`` (e.g. ``--bends-deg=-80,0,80``), as given; ``hint``
    ends the error message."""
    try:
        return [float(v) for v in text.split(",")]
    except ValueError:
        raise UserError(f"{option} {text!r}: expected comma-separated degrees{hint}") from None


def int_list(text: str, option: str) -> list[int]:
    """Comma-separated integers of ``option`` (e.g. ``--seeds 1,2,3``)."""
    try:
        values = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        values = []
    if not values:
        raise UserError(f"{option} {text!r}: expected comma-separated integers, e.g. 1,2,3")
    return values


def truth_for(estimate: str, thetas: np.ndarray, truth: str, psis: bool = False
              ) -> Any:
    """The ground-truth angles of sequence folder ``truth``, checked against an estimate's;
    with ``psis``, the pair ``(thetas, psis)`` (``psis`` ``None`` for a planar truth)."""
    from apcc_graph.io import load_sequence

    seq = load_sequence(truth)
    if seq.thetas is None:
        raise UserError(f"{truth}: frames.csv has no ground-truth theta columns")
    if seq.thetas.shape != thetas.shape:
        raise UserError(f"{estimate}: {thetas.shape[0]} frames x {thetas.shape[1]} segments, "
                        f"but {truth} has {seq.thetas.shape[0]} x {seq.thetas.shape[1]}")
    return (seq.thetas, seq.psis) if psis else seq.thetas
