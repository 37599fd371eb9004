"""armexp: run, sweep, compare and report DRL motion planning on robust low-level control.

Reproduces Heydari Shahna et al., "Integrating DeepRL with Robust Low-Level Control in Robotic
Manipulators for Non-Repetitive Reaching Tasks" (ICMA 2024). See README.md and docs/design.md.
"""

import os

from armexp import jit_cache

__version__ = "0.1.0"

# Before any compiled kernel is loaded: numba's cache keyed by the kernels' sources.
jit_cache.configure()

# Stages download small artifacts often (configs, gains, models): MLflow's per-download progress
# bars would fill the terminal. Set on importing armexp, before any download, and inherited by the
# processes armexp starts (sweep workers, vectorised environments). A user's own setting wins.
os.environ.setdefault("MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR", "false")

try:  # registration needs gymnasium only; the report runs even where the envs are not importable
    from armexp.envs import register_envs as _register_envs
except ImportError:  # pragma: no cover
    pass
else:
    _register_envs()
