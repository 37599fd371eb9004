"""`armexp simulate`: one closed-loop run of the configured controller on a reference scenario.

Logs tracking metrics (`armexp.sim.metrics`), run time, and the 1 kHz trajectory as the artifact
``trajectory.parquet`` (columns `armexp.sim.trajectory.trajectory_columns`; evaluation uses the
same).
A diverging run is an outcome: it is logged (``diverged`` = 1) and the run still FINISHES.
"""

from __future__ import annotations

import logging
import time

import mlflow
import numpy as np
import pandas as pd
from omegaconf import DictConfig

from armexp.builders import build_plant, build_scenario, controller_gains
from armexp.reads import Reads
from armexp.sim.metrics import tracking_metrics
from armexp.sim.simulator import Simulator
from armexp.sim.trajectory import trajectory_columns
from armexp.tracking import artifacts, stage_runs

log = logging.getLogger(__name__)
#: What simulate reads of the config (`armexp.reads`): the plant, the controller and its gains,
#: the scenario, the reference between actions (``env.reference``) and the seed of the
#: disturbance draws; the run name and store are not hashed.
READS = Reads(
    "simulate",
    hashed=("seed", "robot", "controller", "scenario", "env.reference"),
    unhashed=("simulate.run_name", "tracking"),
    earlier=(("seed", "robot", "controller", "scenario"),),  # before env.reference was hashed
)


def run(composed: DictConfig) -> stage_runs.StageResult:
    """Simulate on `READS`' view of the composed config; the run logs the composed config."""
    cfg = READS.view(composed)
    name = cfg.simulate.run_name
    with stage_runs.stage_run(composed, "simulate", run_name=name, reads=READS) as active:
        plant = build_plant(cfg)
        scenario = build_scenario(cfg)
        sim = Simulator(
            plant,
            str(cfg.controller.name),
            controller_gains(cfg),
            q0=scenario.q0 + scenario.offset,
            qd0=scenario.q0,
            seed=int(cfg.seed),
            reference=str(cfg.env.reference),
        )
        chunks = []
        start = time.perf_counter()
        for cmd in scenario.commands:
            rows = sim.advance(cmd, scenario.hold_steps, log=True)
            assert rows is not None
            chunks.append(rows)
            if sim.diverged:
                break
        wall = time.perf_counter() - start
        rows = np.concatenate(chunks)
        n = plant.arm.n
        metrics = tracking_metrics(rows, n, plant.arm.lengths_array)
        metrics.update(
            diverged=float(sim.diverged),
            n_steps=float(rows.shape[0]),
            sim_wall_time_s=wall,
            sim_steps_per_s=rows.shape[0] / wall if wall > 0 else float("nan"),
        )
        mlflow.log_metrics({k: v for k, v in metrics.items() if np.isfinite(v)})
        artifacts.log_dataframe(
            pd.DataFrame(rows, columns=trajectory_columns(n)), "trajectory.parquet"
        )
        log.info(
            "simulate run %s: rms_e1=%.3g rad, convergence_time=%.3g s, diverged=%s",
            active.info.run_id,
            metrics["rms_e1"],
            metrics["convergence_time"],
            sim.diverged,
        )
        print(
            f"simulate: run {active.info.run_id} | rms |e1| {metrics['rms_e1']:.3g} rad | "
            f"converged in {metrics['convergence_time']:.3g} s | diverged: {sim.diverged}"
        )
        return stage_runs.StageResult(active.info.run_id, metrics)
