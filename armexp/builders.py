"""Config → simulation objects. The only bridge between OmegaConf and the ML-free `armexp.sim`."""

from __future__ import annotations

import numpy as np
from omegaconf import DictConfig

from armexp.sim import scenario as scenarios
from armexp.sim.controllers import KINDS, gain_vector
from armexp.sim.model import SOURCE_DQ, SOURCE_Q, ArmModel, Array, Plant, Uncertainty


def build_arm(robot: DictConfig) -> ArmModel:
    return ArmModel(
        lengths=tuple(float(x) for x in robot.lengths),
        masses=tuple(float(x) for x in robot.masses),
        gravity=float(robot.gravity),
    )


def build_uncertainty(robot: DictConfig) -> Uncertainty:
    """F and τ_d from ``robot.uncertainty`` (1-based joints in config, 0-based in the core)."""
    n = len(robot.lengths)
    unc = robot.uncertainty
    if not unc.enabled:
        return Uncertainty.off(n)
    rows = [
        [t.joint - 1, t.amp, t.freq, SOURCE_Q if t.source == "q" else SOURCE_DQ, t.of - 1]
        for t in unc.f_terms
    ]

    def vec(key: str) -> Array:
        v = unc[key]
        return np.zeros(n) if v is None else np.asarray(list(v), dtype=np.float64)

    return Uncertainty(
        np.asarray(rows, dtype=np.float64).reshape(-1, 5),
        vec("tau_d_cos_amp"),
        vec("tau_d_cos_freq"),
        vec("tau_d_rand_amp"),
    )


def build_plant(cfg: DictConfig) -> Plant:
    limit = cfg.robot.torque_limit
    return Plant.build(
        build_arm(cfg.robot),
        build_uncertainty(cfg.robot),
        None if limit is None else np.asarray(list(limit), dtype=np.float64),
        dt=float(cfg.controller.dt),
    )


def controller_kind(cfg: DictConfig) -> int:
    return KINDS[str(cfg.controller.name)]


def controller_gains(cfg: DictConfig) -> Array:
    return gain_vector(controller_kind(cfg), dict(cfg.controller.gains), len(cfg.robot.lengths))


def per_joint(values: list[float], n: int) -> Array:
    """A 1- or n-entry config list as an n-vector."""
    return np.broadcast_to(np.asarray(values, dtype=np.float64), (n,)).copy()


def build_scenario(cfg: DictConfig) -> scenarios.Scenario:
    sc = cfg.scenario
    robot = cfg.robot
    n = len(robot.lengths)
    q0 = np.asarray(list(robot.q0), dtype=np.float64)
    offset = per_joint(list(sc.offset), n)
    bound = np.asarray(list(robot.velocity_bound), dtype=np.float64)
    dt = float(cfg.controller.dt)
    if sc.kind == "switching":
        rng = np.random.default_rng(int(sc.seed))
        return scenarios.switching(
            rng, bound, sc.duration, sc.switch_period, dt, q0, offset, sc.scale
        )
    if sc.kind == "hold":
        return scenarios.hold(sc.duration, dt, q0, offset)
    return scenarios.sine(bound, sc.duration, sc.period, dt, q0, offset, sc.scale)
