"""armexp: run, sweep, compare and report DRL motion planning on robust low-level control.

Reproduces Heydari Shahna et al., "Integrating DeepRL with Robust Low-Level Control in Robotic
Manipulators for Non-Repetitive Reaching Tasks" (ICMA 2024). See README.md and docs/design.md.
"""

__version__ = "0.1.0"

try:  # registration needs gymnasium only; the report runs even where the envs are not importable
    from armexp.envs import register_envs as _register_envs
except ImportError:  # pragma: no cover
    pass
else:
    _register_envs()
