"""Values whose size or form suggests other units or conventions than a file's.

They are read as written, with a :class:`UnitsWarning` that names the file and the key or
columns: a length in millimetres where metres are expected, quaternion columns in the order
``x, y, z, w`` where ``w, x, y, z`` is the format's.
"""

from __future__ import annotations


class UnitsWarning(UserWarning):
    """A value whose size or form suggests other units or conventions than the file's
    (millimetres where metres are expected, a quaternion written scalar-last); it is read as
    written."""


PLAUSIBLE_LENGTH_M = 5.0
"""Longest continuum-robot segment (or tip position) taken without a :class:`UnitsWarning`,
metres: tendon-driven and concentric-tube robots are centimetres to a metre or two long."""
