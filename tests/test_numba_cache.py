"""The numba kernels are compiled once and loaded from disk by later processes."""

from __future__ import annotations

import importlib
import os
import subprocess
import sys
from pathlib import Path

import pytest

KERNEL_MODULES = ("apcc_graph.factors.chain_jit", "apcc_graph.factors.reduced_jit",
                  "apcc_graph.factors.triangulation_jit", "apcc_graph.frontend.pair_jit",
                  "apcc_graph.frontend.ransac_jit", "apcc_graph.frontend.spatial_jit")

CALL = """
import numpy as np
from apcc_graph.factors.chain_jit import fixed_plane_poses
x = np.array([[0.1, -0.2], [0.2, 0.1]])
segments = np.array([[0.1, 0.02, 0.2, 0.5], [0.1, 0.02, 0.2, 0.5]])
poses, _ = fixed_plane_poses(x, segments, np.zeros(2), np.eye(4), np.eye(4)[None], True)
assert np.isfinite(poses).all()
print("hits", fixed_plane_poses.stats.cache_hits, "misses", fixed_plane_poses.stats.cache_misses)
"""


def _run(cache: Path) -> str:
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache), "NUMBA_DEBUG_CACHE": "1"}
    done = subprocess.run([sys.executable, "-c", CALL], capture_output=True, text=True,
                          env=env, timeout=300)
    assert done.returncode == 0, done.stderr
    return done.stdout


def test_a_second_process_loads_the_kernel_from_the_cache(tmp_path: Path) -> None:
    cache = tmp_path / "numba"
    first = _run(cache)
    assert "data saved" in first and "misses" in first
    files = sorted(p.relative_to(cache) for p in cache.rglob("*") if p.is_file())
    assert any(p.suffix == ".nbi" for p in files)
    second = _run(cache)
    assert "data loaded" in second and "data saved" not in second
    assert "index saved" not in second
    assert sorted(p.relative_to(cache) for p in cache.rglob("*") if p.is_file()) == files


@pytest.mark.parametrize("name", KERNEL_MODULES)
def test_every_kernel_is_cacheable(name: str) -> None:
    """Each compiled function of a kernel module has a disk cache (a kernel numba cannot
    cache, e.g. one closing over a function, would be compiled again by every process)."""
    from numba.core.caching import NullCache
    from numba.core.registry import CPUDispatcher

    module = importlib.import_module(name)
    kernels = [v for v in vars(module).values() if isinstance(v, CPUDispatcher)
               and v.py_func.__module__ in (name, module.__name__)]
    assert kernels
    for kernel in kernels:
        assert not isinstance(kernel._cache, NullCache), kernel.py_func.__qualname__


def test_a_read_only_install_caches_in_the_temporary_directory(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """Neither the package's folders nor the user's cache writable, no NUMBA_CACHE_DIR: the
    kernels are cached in a folder of the temporary directory (numba would refuse to decorate
    them and the package would not import); with a writable one, numba's choice stands."""
    from numba.core import config

    from apcc_graph.model import kernel_cache

    monkeypatch.setattr(config, "CACHE_DIR", "")
    monkeypatch.setattr(kernel_cache.tempfile, "gettempdir", lambda: str(tmp_path))
    monkeypatch.setattr(kernel_cache, "_writable", lambda folder: True)
    assert kernel_cache.ensure_cache_dir() is None and config.CACHE_DIR == ""
    monkeypatch.setattr(kernel_cache, "_writable", lambda folder: False)
    chosen = kernel_cache.ensure_cache_dir()
    assert chosen is not None and Path(chosen).parent == tmp_path and Path(chosen).is_dir()
    assert config.CACHE_DIR == chosen
    monkeypatch.setattr(config, "CACHE_DIR", "/somewhere/else")
    assert kernel_cache.ensure_cache_dir() is None  # NUMBA_CACHE_DIR given: left alone


@pytest.mark.parametrize("case", ["missing", "ours", "open to others", "another user's",
                                  "a link", "a file"])
def test_the_temporary_cache_folder_is_used_only_when_private(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path, case: str) -> None:
    """The fallback ``apcc-graph-numba-<uid>`` is used only when it is a real folder of this
    user's with mode 0700 (made so when missing); a folder another user owns (os.getuid
    replaced), one others can write to, a symbolic link or a file is not: a new private folder
    of the process's own is used instead (numba's cache index is a pickle, loaded as code)."""
    import stat

    from numba.core import config

    from apcc_graph.model import kernel_cache

    monkeypatch.setattr(config, "CACHE_DIR", "")
    monkeypatch.setattr(kernel_cache, "_writable", lambda folder: False)
    temp = tmp_path / "tmp"
    temp.mkdir()
    monkeypatch.setattr(kernel_cache.tempfile, "tempdir", str(temp))
    uid = os.getuid()
    fixed = temp / f"apcc-graph-numba-{uid}"
    if case in ("ours", "another user's"):
        fixed.mkdir(mode=0o700)
    elif case == "open to others":
        fixed.mkdir()
        fixed.chmod(0o777)
    elif case == "a link":
        (tmp_path / "elsewhere").mkdir(mode=0o700)
        fixed.symlink_to(tmp_path / "elsewhere")
    elif case == "a file":
        fixed.write_text("")
    if case == "another user's":
        monkeypatch.setattr(kernel_cache.os, "getuid", lambda: uid + 1)
        fixed = fixed.rename(temp / f"apcc-graph-numba-{uid + 1}")  # the name it looks for
    chosen = Path(kernel_cache.ensure_cache_dir() or "")
    assert config.CACHE_DIR == str(chosen) and chosen.parent == temp
    info = os.lstat(chosen)
    assert stat.S_ISDIR(info.st_mode) and stat.S_IMODE(info.st_mode) == 0o700
    assert info.st_uid == os.stat(temp).st_uid
    if case in ("missing", "ours"):
        assert chosen == fixed
    else:
        assert chosen != fixed and chosen.name.startswith("apcc-graph-numba-")
