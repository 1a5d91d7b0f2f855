"""Which implementation the projection model's hot loops run: compiled or numpy.

``"numba"`` (the default) runs the compiled kernels (:mod:`apcc_graph.factors.reduced_jit`,
:mod:`apcc_graph.factors.chain_jit`); ``"numpy"`` runs the vectorised numpy reference they are
tested against. A function that takes ``engine=None`` uses the current default, which
:func:`use_engine` changes for a block (a benchmark's peer run, an equivalence test)::

    with use_engine("numpy"):
        estimate(sequence, method="smoother")   # the numpy reference throughout
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

ENGINES = ("numba", "numpy")
_current = ["numba"]


def resolve(engine: str | None) -> str:
    """``engine``, or the current default when ``None``.

    Raises:
        ValueError: an engine not in :data:`ENGINES`.
    """
    name = _current[0] if engine is None else engine
    if name not in ENGINES:
        raise ValueError(f"engine = {name!r}: expected one of {', '.join(map(repr, ENGINES))}")
    return name


@contextmanager
def use_engine(engine: str) -> Iterator[None]:
    """Make ``engine`` the default inside the block (restored after, also on an error)."""
    previous = _current[0]
    _current[0] = resolve(engine)
    try:
        yield
    finally:
        _current[0] = previous
