"""Every gtsam key of the library's factor graphs, and the window's elimination groups.

One letter per kind of variable; the index packs what the variable belongs to:

========  ====================  ==========================================  ==========
letter    variable              index                                       value
========  ====================  ==========================================  ==========
``x``     a frame's bends       the frame                                   ``Vector``
``t``     a segment tip's pose  ``frame * MAX_SEGMENTS + segment``          ``Pose3``
``p``     a camera's pose       ``frame * MAX_CAMERAS + camera``            ``Pose3``
``l``     a track's point       ``camera * 2**32 + number``                 ``Point3``
``c``     a segment's model     the segment: its ``(k, delta_max)``         ``Vector2``
``m``     a camera's mount      the camera: its ``tip_T_cam``               ``Pose3``
========  ====================  ==========================================  ==========

Frames are graph frames (0-based), segments and cameras 0-based (a camera is the segment it
rides on). A track's point is numbered per camera: by its track id in a batch, by a serial
number in a smoother (a track cut into pieces, or seen again after a restart, gets a new
point). :func:`describe` turns a key back into words for error messages.
"""

from __future__ import annotations

import gtsam

MAX_SEGMENTS = 64
"""Tip keys leave room for this many segments per frame."""

MAX_CAMERAS = 64
"""Camera-pose keys leave room for this many cameras per frame."""

POINTS_PER_CAMERA = 2**32
"""Point keys leave room for this many points per camera."""


def frame_key(frame: int) -> int:
    """Frame ``frame``'s vector (its bends, in the robot's parameterisation)."""
    return int(gtsam.symbol("x", frame))


def tip_key(frame: int, segment: int) -> int:
    """Segment ``segment``'s ``world_T_tip`` (a ``Pose3``) at frame ``frame``."""
    if not 0 <= segment < MAX_SEGMENTS:
        raise ValueError(f"segment {segment}: expected 0 <= segment < {MAX_SEGMENTS}")
    return int(gtsam.symbol("t", frame * MAX_SEGMENTS + segment))


def camera_pose_key(frame: int, camera: int) -> int:
    """Camera ``camera``'s ``world_T_cam`` (a ``Pose3``) at frame ``frame``."""
    if not 0 <= camera < MAX_CAMERAS:
        raise ValueError(f"camera {camera}: expected 0 <= camera < {MAX_CAMERAS}")
    return int(gtsam.symbol("p", frame * MAX_CAMERAS + camera))


def point_key(camera: int, number: int) -> int:
    """Point ``number`` of camera ``camera``'s tracks (a ``Point3``, world frame, metres)."""
    if not 0 <= number < POINTS_PER_CAMERA:
        raise ValueError(f"point {number}: expected 0 <= number < {POINTS_PER_CAMERA}")
    return int(gtsam.symbol("l", camera * POINTS_PER_CAMERA + number))


def calibration_key(segment: int) -> int:
    """Segment ``segment``'s ``(k, delta_max)`` (a ``Vector2``; radians for ``delta_max``)
    when self-calibrating."""
    return int(gtsam.symbol("c", segment))


def mount_key(camera: int) -> int:
    """Camera ``camera``'s mounting ``tip_T_cam`` (a ``Pose3``; metres) when calibrating the
    mounts."""
    return int(gtsam.symbol("m", camera))


def kind(key: int) -> str:
    """The letter of ``key``'s kind (``"x"``, ``"t"``, ...; table above)."""
    return chr(gtsam.Symbol(key).chr())


def elimination_group(key: int) -> int:
    """A smoother window's elimination order: points first (each point's own block is
    positive definite thanks to its prior, so Cholesky never meets a cancelled pivot), then
    the poses, then the frame vectors at the root of the Bayes tree (their marginals, asked
    for every frame, then cost little)."""
    letter = kind(key)
    return 0 if letter == "l" else 2 if letter == "x" else 1


def describe(key: int) -> str:
    """What the variable ``key`` is, in words, e.g. ``"frame 42's bends"``."""
    symbol = gtsam.Symbol(key)
    letter, index = chr(symbol.chr()), symbol.index()
    if letter == "x":
        return f"frame {index}'s bends"
    if letter == "t":
        frame, segment = divmod(index, MAX_SEGMENTS)
        return f"frame {frame}'s segment {segment + 1} tip"
    if letter == "p":
        frame, camera = divmod(index, MAX_CAMERAS)
        return f"frame {frame}'s camera {camera + 1} pose"
    if letter == "l":
        camera, number = divmod(index, POINTS_PER_CAMERA)
        return f"camera {camera + 1}'s point {number}"
    if letter == "c":
        return f"segment {index + 1}'s k and delta_max"
    if letter == "m":
        return f"camera {index + 1}'s mount"
    return f"variable {letter}{index}"
