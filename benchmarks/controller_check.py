"""Are the tuned controllers usable? Paper-budget CSO of both controllers, then the holds and the
switching scenario that the issue names, on the compiled closed loop.

Run: ``python benchmarks/controller_check.py`` (extra Hydra overrides after the options, e.g.
``robot.torque_limit=null``). About 20 s on 2 cores.

Prints, for the CSO-tuned PID and adaptive gains (``tuner=cso_paper``, the default robot) and for
the paper's adaptive gains:

* PID: ``scenario=hold`` (0.05 rad offset, 1 s) at ``robot.q0=[0.5, 0.05]`` and at every pose of
  the tuner's stability grid: max |τ| per joint, the share of steps where τ changes sign from
  the previous step (chatter) over the last 0.5 s, and the final ‖e1‖;
* adaptive: the default ``scenario=switching`` (2 s): peak |τ| over the run and after the first
  0.1 s, time at the torque limit, RMS ‖e1‖ after 0.1 s;
* PASS/MISS: no chatter (sign changes on < 5 % of steps), τ within the limit, and the tuned
  adaptive peak within the limit and within 2× the paper's 400 N·m.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from armexp.builders import build_plant, build_scenario
from armexp.config import compose_config
from armexp.sim.controllers import ADAPTIVE, PAPER_GAINS, gain_mapping, gain_vector
from armexp.sim.simulator import Simulator
from armexp.sim.trajectory import trajectory_columns
from armexp.stages.tune import build_objective, search_box
from armexp.tune import cuckoo_search
from armexp.tune.stability import pose_grid

CHATTER = 0.05


def tune(overrides: list[str]) -> tuple[np.ndarray, float]:
    cfg = compose_config(["tuner=cso_paper", *overrides])
    obj = build_objective(cfg)
    _, lower, upper = search_box(cfg)
    t = cfg.tuner
    res = cuckoo_search(
        obj, lower, upper, n_nests=int(t.n_nests), n_iterations=int(t.n_iterations),
        pa=float(t.pa), beta=float(t.beta), step_scale=float(t.step_scale), seed=int(t.seed),
        abandon=str(t.abandon),
    )  # fmt: skip
    return res.best_x, obj.gain_margin(res.best_x)


def run(overrides: list[str], gains: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The simulate stage's closed loop for a composed scenario; (τ, ‖e1‖) per step."""
    cfg = compose_config(overrides)
    plant = build_plant(cfg)
    sc = build_scenario(cfg)
    sim = Simulator(
        plant, str(cfg.controller.name), gains, q0=sc.q0 + sc.offset, qd0=sc.q0,
        reference=str(cfg.env.reference),
    )  # fmt: skip
    rows = np.concatenate([sim.advance(c, sc.hold_steps, log=True) for c in sc.commands])
    cols = trajectory_columns(plant.arm.n)
    n = plant.arm.n
    tau = rows[:, [cols.index(f"tau_{j}") for j in range(1, n + 1)]]
    e1 = rows[:, 1 : 1 + n] - rows[:, 1 + n : 1 + 2 * n]
    return tau, np.linalg.norm(e1, axis=1)


def sign_changes(tau: np.ndarray) -> float:
    late = tau[-500:]
    return float((np.sign(late[1:]) * np.sign(late[:-1]) < 0).mean(axis=0).max())


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("overrides", nargs="*")
    args = ap.parse_args()
    extra = list(args.overrides)
    cfg = compose_config(extra)
    limit = build_plant(cfg).torque_limit
    ok = True

    pid, pid_margin = tune(["controller=pid", *extra])
    print(f"torque limit: {limit.tolist()} N.m")
    print(f"PID (cso_paper): {gain_mapping(1, pid, 2)} | gain margin {pid_margin:.3g}")
    lower = np.asarray(list(cfg.robot.joint_lower))
    upper = np.asarray(list(cfg.robot.joint_upper))
    poses = [np.array([0.5, 0.05]), *pose_grid(lower, upper, 9)]
    print("  hold 1 s, 0.05 rad offset | q0 | max|tau| (N.m) | sign changes | final |e1| (rad)")
    for pose in poses:
        q0 = f"robot.q0=[{pose[0]:.6g},{pose[1]:.6g}]"
        tau, e = run(["controller=pid", "scenario=hold", q0, *extra], pid)
        flips = sign_changes(tau)
        peak = np.abs(tau).max(axis=0)
        good = flips < CHATTER and bool(np.all(peak <= limit))
        ok &= good
        print(
            f"  {'ok  ' if good else 'FAIL'} | [{pose[0]:+.3f}, {pose[1]:+.3f}] | "
            f"{peak.round(1).tolist()} | {100 * flips:.1f} % | {e[-1]:.2e}"
        )

    adaptive, margin = tune(extra)
    print(f"adaptive (cso_paper): {gain_mapping(ADAPTIVE, adaptive, 2)} | gain margin {margin:.3g}")
    print("  switching 2 s | peak |tau| run / after 0.1 s (N.m) | at limit | RMS |e1| > 0.1 s")
    for name, gains in (("tuned", adaptive), ("paper", gain_vector(ADAPTIVE, PAPER_GAINS, 2))):
        tau, e = run(extra, gains)
        peak = float(np.abs(tau).max())
        late = float(np.abs(tau[100:]).max())
        at_limit = float((np.abs(tau) >= limit).any(axis=1).mean())
        line = (
            f"  {name:<5} | {peak:.0f} / {late:.0f} | {100 * at_limit:.1f} % | "
            f"{np.sqrt(np.mean(e[100:] ** 2)):.2e}"
        )
        if name == "tuned":
            good = peak <= min(float(limit.max()), 800.0) and bool(np.all(np.abs(tau) <= limit))
            ok &= good
            line += f" | {'PASS' if good else 'MISS'} (<= limit and <= 2 x 400 N.m)"
        print(line)
    print(f"overall: {'PASS' if ok else 'MISS'}")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
