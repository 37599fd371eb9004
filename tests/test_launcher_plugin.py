"""Hydra finds armexp's Ray launcher (`hydra/launcher=ray`) in an editable install as in a
regular one.

Each check runs in a fresh interpreter outside the checkout: pytest puts the checkout on
``sys.path`` (``pythonpath`` in pyproject.toml), which would show Hydra's plugin scan the
launcher's folder and hide what an installed ``armexp`` command sees.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
OURS = "hydra_plugins.armexp_launcher.ray_launcher.RayLauncher"

# What the command does before it starts a sweep (`--info plugins`: list the plugins, run no
# job), then the launchers Hydra would instantiate `hydra/launcher=<name>` from.
LIST_LAUNCHERS = """
import armexp
from armexp.cli import main
from hydra.core.plugins import Plugins
from hydra.plugins.launcher import Launcher

assert main(["simulate", "--info", "plugins"]) == 0
print("ARMEXP", armexp.__file__)
for c in Plugins.instance().discover(Launcher):
    print("LAUNCHER", f"{c.__module__}.{c.__name__}")
"""


def _launchers(python: str | Path, cwd: Path) -> tuple[list[str], str]:
    """(launcher classes Hydra knows, where ``armexp`` was imported from) as ``python`` sees
    them, run in ``cwd`` without ``PYTHONPATH``."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    res = subprocess.run(
        [str(python), "-c", LIST_LAUNCHERS],
        cwd=cwd, env=env, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-4000:]
    lines = [line.split(" ", 1) for line in res.stdout.splitlines() if " " in line]
    (where,) = [rest for tag, rest in lines if tag == "ARMEXP"]
    return [rest for tag, rest in lines if tag == "LAUNCHER"], where


@pytest.mark.long
def test_hydra_finds_the_armexp_ray_launcher_in_this_install(tmp_path: Path) -> None:
    """The install the tests run from (the README's: ``pip install -e``)."""
    launchers, _ = _launchers(sys.executable, tmp_path)
    assert launchers.count(OURS) == 1
    assert "hydra_plugins.hydra_joblib_launcher.joblib_launcher.JoblibLauncher" in launchers


@pytest.mark.slow
@pytest.mark.parametrize("editable", [True, False], ids=["editable", "regular"])
def test_hydra_finds_the_armexp_ray_launcher_after_a_fresh_install(
    tmp_path: Path, editable: bool
) -> None:
    """``pip install [-e] .`` into a new environment that borrows this one's dependencies
    (``--no-deps``: nothing is downloaded)."""
    src = tmp_path / "src"  # a copy: a regular install builds inside the source tree
    for name in ("armexp", "conf", "hydra_plugins"):
        shutil.copytree(ROOT / name, src / name, ignore=shutil.ignore_patterns("__pycache__"))
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, src / name)
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    python = venv / "bin" / "python"
    site = subprocess.run(
        [str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        check=True, capture_output=True, text=True,
    ).stdout.strip()  # fmt: skip
    # This environment's packages after the new one's own (a path line in a .pth file): pip,
    # setuptools and armexp's dependencies; an armexp installed here is outside the new
    # environment, so pip leaves it alone.
    (Path(site) / "_deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    pip = [str(python), "-m", "pip", "install", "-q", "--no-deps", "--no-build-isolation"]
    res = subprocess.run(
        [*pip, *(["-e"] if editable else []), str(src)],
        cwd=tmp_path, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-4000:]
    launchers, where = _launchers(python, tmp_path)
    assert Path(where).is_relative_to(src if editable else Path(site))
    assert launchers.count(OURS) == 1
