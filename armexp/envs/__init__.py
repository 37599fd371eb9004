"""Gymnasium environments of armexp; ``import armexp`` registers ``armexp/Reach-v0``."""

from __future__ import annotations

ENV_ID = "armexp/Reach-v0"


def register_envs() -> None:
    import gymnasium

    if ENV_ID not in gymnasium.registry:
        # The environment bounds its own episodes (max_steps), so no TimeLimit wrapper on top.
        gymnasium.register(id=ENV_ID, entry_point="armexp.envs.factory:make_reach")
