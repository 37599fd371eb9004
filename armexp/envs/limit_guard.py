"""A joint-limit guard on the agent's action: the velocity reference is clipped so that the
reference position q_d stays ``margin`` inside the joint limits and can always stop there.

Table I ends an episode at −50 when a joint leaves its limits. With the guard an action that
would carry the reference past ``limit − margin`` is cut to the largest that still lets the next
action stop it there, so the arm can be driven at full speed towards a limit and come to rest
beside it; the agent's action keeps its meaning everywhere else. The guard reads only the
reference (the integral of the agent's own commands from the known start) and the arm's joint
limits (the bounds of the observation's joint angles): no planner, no obstacle knowledge.

Under the ramp reference (`armexp.sim.step.reference_velocity`) a command v after the previous one
v₀ moves q_d by T (v₀ + v)/2 over the action period T; stopping from v in the next period moves it
T v/2 more. Both fit in the room r = (upper − margin − q_d) when

    v ≤ r / T − v₀ / 2,

and symmetrically towards the lower limit. Under the hold reference q_d moves T v, so v ≤ r / T.
At rest at the guarded limit (r = 0, v₀ = 0) the bound is 0: no chatter.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from armexp.sim.model import Array


@njit(cache=True)
def guarded_action(
    action: Array,
    q_d: Array,
    command: Array,
    bound: Array,
    lower: Array,
    upper: Array,
    margin: float,
    period: float,
    ramp: bool,
) -> Array:
    """``action`` (fractions of ``bound``, clipped to [−1, 1]) cut so that the reference stays
    within [lower + margin, upper − margin]; ``command`` is the last commanded q̇_d (rad/s).
    Compiled: `armexp.envs.kernel.env_step` calls it inside the environment step."""
    out = np.empty(action.shape[0])
    for j in range(action.shape[0]):
        carry = 0.5 * command[j] if ramp else 0.0
        room_up = (upper[j] - margin - q_d[j]) / period
        room_down = (q_d[j] - lower[j] - margin) / period
        highest = min(max((room_up - carry) / bound[j], -1.0), 1.0)
        # Outside the guarded band already (a start there): the bound that heads back wins.
        lowest = min(min(max((-room_down - carry) / bound[j], -1.0), 1.0), highest)
        out[j] = min(max(min(max(float(action[j]), -1.0), 1.0), lowest), highest)
    return out
