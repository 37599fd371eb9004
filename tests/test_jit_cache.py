"""numba's cache folder is named by the compiled modules' sources (`armexp.jit_cache`), so a
change to a callee cannot leave a caller's stale machine code in use."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from armexp import jit_cache


def _package(root: Path) -> Path:
    for package in jit_cache.COMPILED:
        (root / package).mkdir(parents=True)
        (root / package / "core.py").write_text("def f():\n    return 1\n")
    return root


def test_any_compiled_source_change_names_a_new_cache(tmp_path: Path) -> None:
    root = _package(tmp_path / "pkg")
    first = jit_cache.cache_dir(root)
    assert first.parent == root / "__pycache__" and first.name.startswith("numba-")
    assert jit_cache.cache_dir(root) == first  # same sources, same cache
    (root / "envs" / "core.py").write_text("def f():\n    return 2\n")  # a callee elsewhere
    second = jit_cache.cache_dir(root)
    assert second != first
    (root / "other.py").write_text("x = 1\n")  # not a compiled package: same cache
    assert jit_cache.cache_dir(root) == second


def test_a_users_cache_folder_is_the_parent_and_old_folders_are_pruned(tmp_path: Path) -> None:
    root = _package(tmp_path / "pkg")
    name = jit_cache.cache_dir(root).name
    assert jit_cache.cache_dir(root, str(tmp_path / "mine")) == tmp_path / "mine" / name
    # A worker inherits the folder already made for it: not nested again.
    assert jit_cache.cache_dir(root, str(tmp_path / "mine" / name)) == tmp_path / "mine" / name
    cache = root / "__pycache__"
    for i in range(5):
        (cache / f"numba-old{i}").mkdir()
        os.utime(cache / f"numba-old{i}", (i, i))
    jit_cache.cache_dir(root)
    left = sorted(p.name for p in cache.glob("numba-*"))
    assert left == ["numba-old3", "numba-old4"]  # the KEEP newest others


@pytest.mark.parametrize("preset", [None, "mine"])
def test_importing_armexp_sets_numbas_cache_for_this_process_and_its_children(
    tmp_path: Path, preset: str | None
) -> None:
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    if preset:
        env["NUMBA_CACHE_DIR"] = str(tmp_path / preset)
    code = (
        "import armexp, numba, os; print(numba.config.CACHE_DIR); "
        "print(os.environ['NUMBA_CACHE_DIR'])"
    )
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         check=True).stdout.split()  # fmt: skip
    assert out[0] == out[1] and Path(out[0]).name.startswith("numba-")
    if preset:
        assert Path(out[0]).parent == tmp_path / preset
