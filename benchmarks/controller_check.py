"""The controllers of a comparison, tuned as carefully as each other, on the compiled closed loop.

Run: ``python benchmarks/controller_check.py [--seed S] [overrides]`` (extra Hydra overrides, e.g.
``robot.torque_limit=null``). About a minute on 2 cores.

Each controller is tuned by the paper-budget CSO (``tuner=cso_paper``, seed S) under the fair
criterion (``itae`` over 1.5 s) and, for the paper's own comparison, under Gaing's W over 0.6 s:

* ``proposed``: the subsystem-based adaptive law; ``no adaptation``: the same gains with b1 = 0
  (ρ̂ ≡ 0), the ablation; ``pid`` and ``computed torque`` (M(q) only): the baselines;
* ``proposed (W)`` and ``pid (W)``: both tuned on the paper's W (the PID the paper compared with);
* ``paper gains``: the paper's published adaptive gains, untuned.

Printed per controller: the tuned gains, the search coordinates on a bound of the box (in log
space), the best objective, the gain margin and the largest adaptive term b1 ρ̂ the tuning
scenarios reached; then Definition 1's decay rate α and ultimate bound α* of ‖e1‖ after the
reference starts 5 mrad and 50 mrad from the arm (switching commands, 1 s,
`armexp.sim.convergence.definition_one`), the tip tracking error (RMS, cm) on 6 s of switching
commands, 6 s of sine commands and 30 s of switching commands from zero error, the peak |τ| and
the share of time at the torque limit on the 6 s switching run, and whether a 1 s hold of a
0.05 rad offset chatters at any pose of the stability grid.

PASS/MISS: every tuned controller within the torque limit and without chatter; the ablation line
says whether adaptation changes anything.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from armexp.builders import build_plant, build_scenario
from armexp.config import compose_config
from armexp.sim.controllers import (
    ADAPTIVE,
    KINDS,
    PAPER_GAINS,
    adaptive_rates,
    gain_mapping,
    gain_vector,
    without_adaptation,
)
from armexp.sim.convergence import definition_one
from armexp.sim.metrics import tracking_metrics
from armexp.sim.simulator import Simulator
from armexp.stages.tune import build_objective, search_space
from armexp.tune import cuckoo_search
from armexp.tune.stability import pose_grid
from benchmarks.pace import measure

CHATTER = 0.05
OFFSETS = (0.005, 0.05)
TRACKING = (
    ("switching 6 s", ["scenario=switching", "scenario.duration=6"]),
    ("sine 6 s", ["scenario=sine", "scenario.duration=6"]),
    ("switching 30 s", ["scenario=switching", "scenario.duration=30"]),
)


@dataclass
class Tuned:
    name: str
    controller: str
    gains: np.ndarray
    note: str


def tune(name: str, overrides: list[str]) -> Tuned:
    cfg = compose_config(["tuner=cso_paper", *overrides])
    obj = build_objective(cfg)
    space = search_space(cfg)
    t = cfg.tuner
    res = cuckoo_search(
        space.objective(obj), space.search_lower, space.search_upper, n_nests=int(t.n_nests),
        n_iterations=int(t.n_iterations), pa=float(t.pa), beta=float(t.beta),
        step_scale=float(t.step_scale), seed=int(t.seed), abandon=str(t.abandon),
    )  # fmt: skip
    best = space.gains(res.best_x)[0]
    crit = obj.criteria(best[None])
    sigma = float(crit.sigma_max[0])
    note = (
        f"{t.objective.criterion} {obj.settings.horizon:g} s: {res.best_f:.4g} | gain margin "
        f"{obj.gain_margin(best):.3g} (at peak b1 rho {sigma:.3g}: "
        f"{obj.gain_margin(best, sigma=sigma):.3g}) | on a bound: "
        f"{', '.join(space.on_bound(best)) or 'none'}"
    )
    return Tuned(name, str(cfg.controller.name), best, note)


def run(overrides: list[str], controller: str, gains: np.ndarray) -> np.ndarray:
    """The simulate stage's closed loop for a composed scenario; its logged rows."""
    cfg = compose_config(overrides)
    plant = build_plant(cfg)
    sc = build_scenario(cfg)
    sim = Simulator(
        plant, controller, gains, q0=sc.q0 + sc.offset, qd0=sc.q0,
        reference=str(cfg.env.reference),
    )  # fmt: skip
    return np.concatenate([sim.advance(c, sc.hold_steps, log=True) for c in sc.commands])


def describe(c: Tuned, extra: list[str], limit: np.ndarray) -> tuple[str, bool, dict[str, float]]:
    """One controller's lines, whether it passes (within the limit, no chatter) and its key
    figures (decay rate at 5 mrad, tip RMS on 6 s of switching)."""
    n = len(limit)
    cfg = compose_config(extra)
    lengths = np.asarray(list(cfg.robot.lengths), float)
    lines = []
    key: dict[str, float] = {}
    for offset in OFFSETS:
        rows = run([*extra, "scenario.duration=1", f"scenario.offset=[{offset}]"], c.controller,
                   c.gains)  # fmt: skip
        e1 = np.linalg.norm(rows[:, 1 : 1 + n] - rows[:, 1 + n : 1 + 2 * n], axis=1)
        d = definition_one(rows[:, 0], e1, offset, 1.0, 1e-4)
        key.setdefault("decay_rate", d["decay_rate"])
        lines.append(
            f"offset {1000 * offset:g} mrad: decay rate {d['decay_rate']:.3g} /s, ultimate bound "
            f"{1000 * d['ultimate_bound']:.3g} mrad, settling {d['settling_time']:.3g} s, "
            f"ITAE {d['itae']:.3g}"
        )
    tips, ok = [], True
    for label, scenario in TRACKING:
        rows = run([*extra, *scenario, "scenario.offset=[0.0]"], c.controller, c.gains)
        metrics = tracking_metrics(rows, n, lengths)
        tips.append(f"{label} {metrics['tip_rms_cm']:.3g}")
        if label == "switching 6 s":
            key["tip_rms_cm"] = metrics["tip_rms_cm"]
            tau = rows[:, 1 + 4 * n : 1 + 5 * n]
            peak = np.abs(tau).max(axis=0)
            at_limit = float((np.abs(tau) >= limit).any(axis=1).mean())
            ok &= bool(np.all(peak <= limit + 1e-9))
    lines.append("tip RMS (cm): " + ", ".join(tips))
    lines.append(f"peak |tau| {np.round(peak).tolist()} N.m, at the limit {100 * at_limit:.1f} %")
    chatter = 0.0
    lower = np.asarray(list(cfg.robot.joint_lower))
    upper = np.asarray(list(cfg.robot.joint_upper))
    for pose in pose_grid(lower, upper, 9):
        q0 = "robot.q0=[" + ",".join(f"{q:.6g}" for q in pose) + "]"
        rows = run([*extra, "scenario=hold", "obstacles=none", q0], c.controller, c.gains)
        late = rows[-500:, 1 + 4 * n : 1 + 5 * n]
        flips = (np.sign(late[1:]) * np.sign(late[:-1]) < 0).mean(axis=0).max()
        chatter = max(chatter, float(flips))
    ok &= chatter < CHATTER
    lines.append(f"holds at the grid poses: sign changes on <= {100 * chatter:.1f} % of steps")
    return "\n    ".join(lines), ok, key


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0, help="the tuner's seed")
    ap.add_argument("overrides", nargs="*")
    args = ap.parse_args()
    print(measure().line())
    extra = list(args.overrides)
    seed = f"tuner.seed={args.seed}"
    limit = build_plant(compose_config(extra)).torque_limit
    n = len(limit)
    print(f"torque limit: {limit.tolist()} N.m; tuner seed {args.seed}")
    proposed = tune("proposed", [*extra, seed])
    paper = gain_vector(ADAPTIVE, PAPER_GAINS, n)
    names = ("a0", "a1", "b1", "c1", "r1")
    adaptive = {k: float(v) for k, v in zip(names, proposed.gains, strict=True)}
    ablation = gain_vector(ADAPTIVE, without_adaptation(adaptive), n)
    controllers = [
        proposed,
        Tuned("no adaptation", "subsystem_adaptive", ablation, "proposed gains, b1 = 0"),
        tune("pid", [*extra, seed, "controller=pid"]),
        tune("computed torque", [*extra, seed, "controller=computed_torque"]),
        tune("proposed (W)", [*extra, seed, "tuner.objective.criterion=gaing"]),
        tune("pid (W)", [*extra, seed, "controller=pid", "tuner.objective.criterion=gaing"]),
        Tuned("paper gains", "subsystem_adaptive", paper, "published, not tuned"),
    ]
    ok = True
    figures: dict[str, dict[str, float]] = {}
    for c in controllers:
        mapping = gain_mapping(KINDS[c.controller], c.gains, n)
        shown = " ".join(
            f"{k}={[float(f'{x:.4g}') for x in v] if isinstance(v, list) else float(f'{v:.4g}')}"
            for k, v in mapping.items()
        )
        if c.controller == "subsystem_adaptive":
            lam, gamma = adaptive_rates(c.gains)
            shown += f" (lambda={lam:.3g}, gamma={gamma:.3g})"
        text, good, figures[c.name] = describe(c, extra, limit)
        if c.name not in ("paper gains",):
            ok &= good
        print(f"{c.name} [{c.controller}]: {shown}\n    {c.note}\n    {text}"
              + ("" if good else "\n    MISS: over the limit or chattering"))  # fmt: skip
    on, off = figures["proposed"], figures["no adaptation"]
    change = {k: off[k] / on[k] - 1.0 for k in on}
    inert = all(abs(v) < 1e-3 for v in change.values())
    print(
        f"ablation: adaptation off changes the tip RMS by {100 * change['tip_rms_cm']:+.2f} % and "
        f"the 5 mrad decay rate by {100 * change['decay_rate']:+.2f} %: adaptation "
        + ("does not measurably contribute" if inert else "contributes")
    )
    print(f"overall: {'PASS' if ok else 'MISS'} (within the torque limit, no chatter)")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
