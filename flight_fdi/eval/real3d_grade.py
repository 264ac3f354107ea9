"""The grade file of the real MEMS recordings' analysis: ``real3d.Settings`` as a YAML grade file
(config/grades/xsens_dot_mimu.yaml; docs/ins3d_real.md, "The bag path").

``flight-fdi analyze --model ins3d BAG --grade config/grades/xsens_dot_mimu.yaml --rows 2`` on a
bag of ``real3d.write_contract_bag`` runs the analysis of ``real3d.analyze``: the IMU values, the
model error allowance and the seed method's short-flight settings come from this file, the
vertical channel, the latency state, the reference noise and the prior from the bag's
description (``real3d.error_model_of``). The grade ``xsens_dot`` is not a calibrated preset, so
``real3d.analyze`` uses tactical's GLR thresholds (``glr3d.thresholds_for``): the file's base.

``grade_file_text`` writes the file from ``Settings``; ``grade_file_differences`` says where a
file and ``Settings`` differ (test/ins3d_eval/test_real3d_cli.py keeps the file equal to
``Settings()``). After a change of the ``Settings`` defaults::

    python -m flight_fdi.eval.real3d_grade config/grades/xsens_dot_mimu.yaml
"""
from __future__ import annotations

import math
import sys
from dataclasses import fields
from pathlib import Path

from ..core.ins3d.grade_file import (KEYS, diagnosis_config_of, grade_thresholds, load_grade,
                                     signature_error_of)
from ..core.ins3d.grades import ImuGrade
from .real3d import Settings

GRADE_FILE = Path(__file__).resolve().parents[2] / "config" / "grades" / "xsens_dot_mimu.yaml"
#: the preset whose GLR thresholds ``real3d.analyze`` uses for the (uncalibrated) xsens_dot grade
BASE = "tactical"
_REL = 1e-9


def _short(v: float) -> float | int:
    """``v`` to 12 significant digits (an integer when it is one): the file's unit conversions
    stay within 1e-11 relative."""
    r = float(f"{v:.12g}")
    return int(r) if r.is_integer() and abs(r) < 1e15 else r


def grade_file_doc(settings: Settings = Settings()) -> dict:
    """The keys of the grade file of ``settings`` (every IMU value given, so only the thresholds
    come from ``BASE``)."""
    g = settings.grade()
    doc: dict = {"name": g.name, "base": BASE}
    doc.update({key: _short(getattr(g, field) / factor) for key, (field, factor) in KEYS.items()})
    if settings.signature_error is not None:
        doc["signature_error_rad"] = _short(settings.signature_error)
    doc["seed_fisher_window"] = int(settings.fisher_window)
    doc["seed_min_valid_steps"] = int(settings.min_valid_steps)
    return doc


def grade_file_text(settings: Settings = Settings()) -> str:
    """The grade file of ``settings`` with a comment saying what it is for."""
    head = ["# The Xsens DOT units of the mimu_quadrotor recordings, calibrated leave-one-out:",
            "# real3d.Settings() as a grade file (written by flight_fdi/eval/real3d_grade.py;",
            "# docs/ins3d_real.md, 'The bag path'). Use on a bag of real3d.write_contract_bag:",
            f"#   flight-fdi analyze --model ins3d BAG --grade config/grades/{GRADE_FILE.name} "
            f"--rows {settings.rows}",
            "# (the bag's description gives the vertical channel, latency and prior). Every IMU",
            f"# value is given; the GLR thresholds are {BASE}'s (xsens_dot is not calibrated)."]
    body = [f"{k}: {v}" for k, v in grade_file_doc(settings).items()]
    return "\n".join(head + body) + "\n"


def _close(a: float, b: float) -> bool:
    return math.isclose(float(a), float(b), rel_tol=_REL, abs_tol=1e-300)


def grade_file_differences(path: str | Path = GRADE_FILE,
                           settings: Settings = Settings()) -> list[str]:
    """Where the grade of the file ``path`` and ``settings`` differ, one line each: IMU values,
    GLR thresholds (a 37-s flight and the calibrated length), the signature error allowed and
    the seed method's rules -- everything ``real3d.analyze`` takes from ``Settings`` besides the
    contract, the reference rows and the bag description's error model."""
    got, want = load_grade(path), settings.grade()
    out = [f"{f.name}: file {getattr(got, f.name)!r}, Settings {getattr(want, f.name)!r}"
           for f in fields(ImuGrade) if f.name != "name"
           and not _close(getattr(got, f.name), getattr(want, f.name))]
    for dur in (None, 37.0):
        a, b = grade_thresholds(got, dur), grade_thresholds(want, dur)
        if a.keys() != b.keys() or not all(_close(a[k], b[k]) for k in a):
            out.append(f"GLR thresholds ({dur or 'calibrated length'} s): file {a}, "
                       f"Settings {b}")
    eps = settings.signature_error if settings.signature_error is not None \
        else signature_error_of(want)
    if not _close(signature_error_of(got), eps):
        out.append(f"signature error: file {signature_error_of(got)!r}, Settings {eps!r}")
    seed = settings.diagnosis()
    if diagnosis_config_of(got) != seed:
        out.append(f"seed method: file {diagnosis_config_of(got)}, Settings {seed}")
    return out


def main(argv: list[str] | None = None) -> int:
    """Write the grade file of ``Settings()`` (to the path given, default ``GRADE_FILE``)."""
    path = Path((argv if argv is not None else sys.argv[1:] or [str(GRADE_FILE)])[0])
    path.write_text(grade_file_text(), encoding="utf-8")
    bad = grade_file_differences(path)
    for line in bad:
        print(line, file=sys.stderr)
    return 1 if bad else 0


if __name__ == "__main__":
    raise SystemExit(main())


__all__ = ["BASE", "GRADE_FILE", "grade_file_differences", "grade_file_doc", "grade_file_text"]
