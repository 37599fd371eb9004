"""The wheel ships every package and the config tree (`pip install .` must work, not just -e)."""

from __future__ import annotations

import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_every_package_and_the_config_tree_are_listed_for_the_wheel() -> None:
    setup = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    listed = set(setup["packages"])
    found = {
        ".".join(p.parent.relative_to(ROOT).parts)
        for top in ("armexp", "hydra_plugins")  # hydra_plugins: armexp's launcher plugin
        for p in (ROOT / top).rglob("__init__.py")
    }
    assert found | {"armexp.conf"} == listed
    assert setup["package-dir"]["armexp.conf"] == "conf"
    assert (ROOT / "conf" / "__init__.py").exists()
    assert setup["package-data"]["armexp.conf"] == ["**/*.yaml"]
