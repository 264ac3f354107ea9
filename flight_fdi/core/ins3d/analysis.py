"""``analyze_ins3d``: the 3-D analysis of one flight as far as it goes today -- the forward
filter with the beta^2 gate and the persistence alarm, and the observability report.

The post-flight parts of issue 15 (backward information filter, two-filter chi^2, body-axis GLR
isolation) are not here yet (docs/ins3d.md, "What is next").
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..kalman import ALARM_RAISED, GateConfig
from .data import NavSteps, RefRows
from .filter import Ins3dForward, run_forward
from .model import Ins3dModel
from .observability import ObservabilityReport, manoeuvres, observability


@dataclass
class Ins3dAnalysis:
    model: Ins3dModel
    forward: Ins3dForward
    observability: ObservabilityReport
    manoeuvres: list[tuple[float, float, str]]

    def summary(self) -> dict:
        """Plain numbers for reports and JSON."""
        f = self.forward
        raised = f.t_ref[f.alarm == ALARM_RAISED]
        names = ("east", "north", "up")[:self.model.rows]
        return {
            "model": "ins3d", "grade": self.model.grade.name, "states": list(self.model.names),
            "updates": int(f.beta2.size), "beta2_mean": float(f.beta2.mean()),
            "beta2_row_mean": dict(zip(names, map(float, f.beta2_row.mean(axis=0)))),
            "gate_exceeded_fraction": float(f.exceeded.mean()),
            "alarms_raised_s": [float(t) for t in raised],
            "final_state": dict(zip(self.model.names, map(float, f.x[-1]))),
            "final_sd": dict(zip(self.model.names, map(float, f.sd[-1]))),
            "observability": self.observability.excited_at,
            "manoeuvres": [list(m) for m in self.manoeuvres],
        }


def analyze_ins3d(steps: NavSteps, refs: RefRows, grade: str = "navigation", rows: int = 2,
                  position: bool = False, vertical: str = "damped", latency: bool = True,
                  ref_markov: tuple[float, float, float] | None = (0.02, 0.03, 30.0),
                  gate: GateConfig = GateConfig(), aligned_prior: bool = True
                  ) -> Ins3dAnalysis:
    """Forward filter + observability report of one flight (see ``bagio.ins3d_input`` for the
    inputs from a bag or a simulated flight)."""
    model = Ins3dModel.from_grade(grade, position=position, rows=rows, vertical=vertical,
                                  latency=latency, ref_markov=ref_markov)
    P0 = model.p0_aligned(steps.C[0], steps.f_n[0], float(steps.lat[0])) if aligned_prior \
        else np.diag(model.p0())
    fwd = run_forward(model, steps, refs, gate=gate, P0=P0)
    obs = observability(model, steps, refs, P0=P0)
    return Ins3dAnalysis(model, fwd, obs, manoeuvres(steps))


__all__ = ["Ins3dAnalysis", "analyze_ins3d"]
