"""``apcc-graph track``: a sequence folder's images into tracks (OpenCV KLT)."""

from __future__ import annotations

import argparse

from apcc_graph.cli.common import FORMATTER, force_option

EXAMPLE = "example:\n  apcc-graph track my_recording --force"


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Add ``track`` to the subcommands."""
    trk = commands.add_parser(
        "track", help="turn a sequence folder's images into tracks (OpenCV KLT)",
        description="Detect Shi-Tomasi corners in images/cam_<i>/<frame:06d>.png and follow "
        "them with pyramidal Lucas-Kanade (forward-backward checked); write tracks/cam_<i>.csv.",
        epilog=EXAMPLE, formatter_class=FORMATTER,
        parents=[force_option("replace tracks files that already hold observations")],
    )
    trk.add_argument("sequence", help="sequence folder with images/")
    trk.set_defaults(run=run)


def run(args: argparse.Namespace) -> str:
    """Track every camera's images and return the files written."""
    from apcc_graph.frontend.tracking import track_sequence

    written = track_sequence(args.sequence, force=args.force, progress=True)
    return "wrote " + ", ".join(str(p) for p in written)
