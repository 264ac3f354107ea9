"""IMU grades from a YAML file (docs/ins3d.md, "IMU grade from a file"), and the resolver that
turns a grade given by name or path into an ``ImuGrade``.

A file names the grade and a ``base`` preset (``grades.GRADES``); every value it does not give
and the GLR thresholds come from the base. Values are in engineering units, the unit in the key
(``KEYS``: key -> ImuGrade field, factor to SI). ``thresholds`` (optional): per hypothesis kind
(step, ramp, jump, outliers) the threshold of the maximum GLR for a flight of
``glr3d.CALIBRATED_LENGTH_S``, and optionally per hypothesis (``glr3d.PER_HYPOTHESIS``, e.g.
``gyro_z_step``: its own threshold; the others use their kind's); longer flights raise them as
the presets' (``glr3d.thresholds_for``). What the file does not give comes from the base, its
per-hypothesis thresholds included -- except those of a kind the file gives (its value then
holds for every hypothesis of that kind not given by name).
``signature_error_rad`` (optional): how far (an angle) the model's fault signatures may be off on
this IMU and platform; a confident isolation must leave room for it against its rival
(``glr3d.settle``; default the grade's axis misalignment, which leaves the gap rule as it is).
Measured on the real MEMS recordings: 0.06-0.25, and 0.33 keeps confident wrong answers rare
there (docs/ins3d_real.md). ``seed_episode_probability`` (optional, in (0, 1)): the seed method's
``DiagnosisConfig.episode_probability`` for this grade -- the upper-tail probability a persistent
J episode's peak must fall below to be declared (default 1e-6, the presets'); ``flight-fdi
calibrate`` sets it so that the grade's nominal flights are rarely declared
(``diagnosis_config_of``).
``seed_fisher_window`` (optional, an integer > 4) and ``seed_min_valid_steps`` (optional, an
integer >= 1): the seed method's Fisher window and the fewest valid steps it analyses
(``DiagnosisConfig``; defaults 50 and 100 -- a short flight with a 1-Hz reference needs less, e.g.
5 and 5 on the real MEMS recordings: config/grades/xsens_dot_mimu.yaml).

Example (config/grades/example_mems_custom.yaml)::

    name: my_mems
    base: mems
    gyro_bias_deg_h: 20
    accel_bias_ug: 2000
    thresholds: {step: 30}
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from ..diagnosis import DiagnosisConfig
from ..errors import CoreError
from .glr3d import PER_HYPOTHESIS, length_growth, thresholds_for
from .grades import DEG_H, DEG_RTH, GRADES, MPS_RTH, UG, ImuGrade

#: the numeric keys of a grade file: key -> (ImuGrade field, SI per unit of the key)
KEYS = {
    "gyro_bias_deg_h": ("gyro_bias", DEG_H),
    "gyro_instability_deg_h": ("gyro_instability", DEG_H),
    "gyro_tau_s": ("gyro_tau_s", 1.0),
    "gyro_arw_deg_rth": ("arw", DEG_RTH),
    "gyro_scale_ppm": ("gyro_scale", 1e-6),
    "gyro_misalign_mrad": ("gyro_misalign", 1e-3),
    "gyro_quantum_rad": ("gyro_quantum", 1.0),
    "accel_bias_ug": ("accel_bias", UG),
    "accel_instability_ug": ("accel_instability", UG),
    "accel_tau_s": ("accel_tau_s", 1.0),
    "accel_vrw_mps_rth": ("vrw", MPS_RTH),
    "accel_scale_ppm": ("accel_scale", 1e-6),
    "accel_misalign_mrad": ("accel_misalign", 1e-3),
    "accel_quantum_mps": ("accel_quantum", 1.0),
    "heading_sigma_deg": ("heading_sigma", math.pi / 180.0),
}
#: keys that must be > 0 (the others >= 0)
POSITIVE = ("gyro_tau_s", "accel_tau_s")
KINDS = ("step", "ramp", "jump", "outliers")
#: the keys of a grade file besides KEYS
_OTHER_KEYS = ("name", "base", "thresholds", "calibration", "signature_error_rad",
               "seed_episode_probability", "seed_fisher_window", "seed_min_valid_steps")
#: the seed method's integer keys: key -> (CustomGrade field, smallest value)
SEED_INTEGERS = {"seed_fisher_window": ("fisher_window", 5),
                 "seed_min_valid_steps": ("min_valid_steps", 1)}
_NAME = re.compile(r"^[A-Za-z0-9_.-]+$")


@dataclass(frozen=True)
class CustomGrade(ImuGrade):
    """A grade that is not a preset: its own GLR thresholds per kind (``KINDS``, for a flight of
    ``glr3d.CALIBRATED_LENGTH_S``) as (kind, value) pairs, then any per hypothesis
    (``glr3d.PER_HYPOTHESIS``) as (name, value) pairs; ``base``: the file's base preset (what
    ``eval.ladder3d`` starts a ladder from; not compared, not in ``numbers``)."""

    thresholds: tuple[tuple[str, float], ...] = ()
    signature_error: float | None = None    # rad; None: the grade's axis misalignment
    episode_probability: float | None = None  # the seed method's; None: DiagnosisConfig's
    fisher_window: int | None = None          # the seed method's; None: DiagnosisConfig's
    min_valid_steps: int | None = None        # the seed method's; None: DiagnosisConfig's
    base: str = field(default="", compare=False)  # the file's base preset ("" from numbers)

    def to_dict(self) -> dict:
        """The fields (SI), the thresholds as a mapping kind -> value."""
        return {**super().to_dict(), "thresholds": dict(self.thresholds)}

    def numbers(self) -> dict[str, float]:
        """The SI values of the ImuGrade fields and ``threshold_<kind>`` (what a recording
        stores; ``from_numbers`` reads them back)."""
        out = {f.name: float(getattr(self, f.name)) for f in fields(ImuGrade) if f.name != "name"}
        out.update({f"threshold_{k}": float(v) for k, v in self.thresholds})
        if self.signature_error is not None:
            out["signature_error"] = float(self.signature_error)
        if self.episode_probability is not None:
            out["episode_probability"] = float(self.episode_probability)
        for f, _ in SEED_INTEGERS.values():
            if getattr(self, f) is not None:
                out[f] = float(getattr(self, f))
        return out

    @classmethod
    def from_numbers(cls, name: str, values: dict[str, float]) -> "CustomGrade":
        try:
            kw = {f.name: float(values[f.name]) for f in fields(ImuGrade) if f.name != "name"}
            thr = tuple((k, float(values[f"threshold_{k}"])) for k in KINDS) + tuple(
                (h, float(values[f"threshold_{h}"])) for h in PER_HYPOTHESIS
                if f"threshold_{h}" in values)
        except KeyError as exc:
            raise CoreError(f"IMU grade {name!r}: value {exc.args[0]!r} missing") from None
        eps, p = values.get("signature_error"), values.get("episode_probability")
        seed = {f: int(values[f]) for f, _ in SEED_INTEGERS.values() if f in values}
        return cls(name, thresholds=thr, signature_error=None if eps is None else float(eps),
                   episode_probability=None if p is None else float(p), **seed, **kw)


def _number(path: str, key: str, value: Any, positive: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, str)):
        raise CoreError(f"grade file {path}: {key} must be a number, got {value!r}")
    try:
        v = float(value)          # a string too: PyYAML reads 1e-5 (no dot) as a string
    except ValueError:
        raise CoreError(f"grade file {path}: {key} must be a number, got {value!r}") from None
    if not math.isfinite(v) or v < 0 or (positive and v == 0):
        raise CoreError(f"grade file {path}: {key} must be a finite number "
                        f"{'> 0' if positive else '>= 0'}, got {value!r}")
    return v


def grade_from_dict(doc: Any, path: str = "<dict>") -> CustomGrade:
    """The grade of a parsed grade file (module docstring); CoreError naming the bad key."""
    if not isinstance(doc, dict):
        raise CoreError(f"grade file {path}: expected a mapping of keys to values")
    unknown = sorted(set(doc) - set(KEYS) - set(_OTHER_KEYS), key=str)
    if unknown:
        raise CoreError(f"grade file {path}: unknown key {unknown[0]!r} (allowed: "
                        f"{', '.join(_OTHER_KEYS)}, {', '.join(KEYS)})")
    if not isinstance(doc.get("calibration", {}), dict):
        raise CoreError(f"grade file {path}: calibration must be a mapping (what `flight-fdi "
                        "calibrate` wrote)")
    name, base = doc.get("name"), doc.get("base")
    if not isinstance(name, str) or not _NAME.match(name):
        raise CoreError(f"grade file {path}: name must be a word of letters, digits, _ . -, "
                        f"got {name!r}")
    if base not in GRADES:
        raise CoreError(f"grade file {path}: base must be a preset ({', '.join(GRADES)}), "
                        f"got {base!r}")
    si = {field: _number(path, key, doc[key], key in POSITIVE) * factor
          for key, (field, factor) in KEYS.items() if key in doc}
    thr = _thresholds(path, base, doc.get("thresholds", {}))
    preset = {f.name: getattr(GRADES[base], f.name) for f in fields(ImuGrade)}
    return CustomGrade(**{**preset, **si, "name": name}, thresholds=thr, base=base,
                       signature_error=_signature_error(path, doc.get("signature_error_rad")),
                       episode_probability=_episode_probability(
                           path, doc.get("seed_episode_probability")),
                       **{f: _integer(path, key, doc[key], least)
                          for key, (f, least) in SEED_INTEGERS.items() if key in doc})


def _signature_error(path: str, value: Any) -> float | None:
    if value is None:
        return None
    v = _number(path, "signature_error_rad", value)
    if v >= math.pi / 2:
        raise CoreError(f"grade file {path}: signature_error_rad must be an angle below pi/2 "
                        f"(1.5708), got {value!r}")
    return v


def _episode_probability(path: str, value: Any) -> float | None:
    if value is None:
        return None
    v = _number(path, "seed_episode_probability", value)
    if not 0.0 < v < 1.0:
        raise CoreError(f"grade file {path}: seed_episode_probability must be a probability "
                        f"within (0, 1), got {value!r}")
    return v


def _integer(path: str, key: str, value: Any, least: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < least:
        raise CoreError(f"grade file {path}: {key} must be an integer >= {least}, got {value!r}")
    return value


def diagnosis_config_of(grade: ImuGrade) -> DiagnosisConfig:
    """The seed method's rules for a grade: ``DiagnosisConfig()`` with a grade file's
    ``seed_episode_probability``, ``seed_fisher_window`` and ``seed_min_valid_steps`` (a preset:
    the defaults)."""
    given = {"episode_probability": getattr(grade, "episode_probability", None),
             **{f: getattr(grade, f, None) for f, _ in SEED_INTEGERS.values()}}
    return DiagnosisConfig(**{k: v for k, v in given.items() if v is not None})


def signature_error_of(grade: ImuGrade) -> float:
    """The relative error (an angle, rad) a confident isolation must allow the model's fault
    signatures (``glr3d.settle``): a grade file's ``signature_error_rad``, else the grade's axis
    misalignment."""
    eps = getattr(grade, "signature_error", None)
    return float(eps) if eps is not None else max(grade.gyro_misalign, grade.accel_misalign)


def _thresholds(path: str, base: str, given: Any) -> tuple[tuple[str, float], ...]:
    """The kinds' thresholds, then the hypotheses' (module docstring: the base's where not
    given; a hypothesis without one uses its kind's, ``glr3d.threshold_of``)."""
    if not isinstance(given, dict):
        raise CoreError(f"grade file {path}: thresholds must be a mapping of kind (or "
                        f"hypothesis) to value ({', '.join(KINDS)}, e.g. gyro_z_step)")
    bad = sorted(set(given) - set(KINDS) - set(PER_HYPOTHESIS), key=str)
    if bad:
        raise CoreError(f"grade file {path}: unknown key 'thresholds.{bad[0]}' (allowed: "
                        f"{', '.join(KINDS)}, or a hypothesis: {', '.join(PER_HYPOTHESIS)})")
    thr = {k: v for k, v in thresholds_for(base).items()     # a kind given: the base's
           if k in KINDS or k.rsplit("_", 1)[-1] not in given}   # hypotheses of it dropped
    thr.update({k: _number(path, f"thresholds.{k}", v, True) for k, v in given.items()})
    return tuple((k, float(thr[k])) for k in (*KINDS, *(h for h in PER_HYPOTHESIS if h in thr)))


def load_grade(path: str | Path) -> CustomGrade:
    """The grade of a YAML grade file (CoreError, one line, for a file that is not one)."""
    import yaml  # PyYAML ships with the ROS wheels

    try:
        text = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise CoreError(f"grade file {path}: cannot read it ({exc.__class__.__name__}: "
                        f"{getattr(exc, 'strerror', None) or exc})") from None
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        where = getattr(exc, "problem_mark", None)
        raise CoreError(f"grade file {path}: not valid YAML"
                        + (f" (line {where.line + 1})" if where else "")) from None
    return grade_from_dict(doc, str(path))


def is_grade_file(name: str) -> bool:
    """Whether a grade given as ``name`` is meant as a file: a YAML name or an existing file."""
    return name.lower().endswith((".yaml", ".yml")) or Path(name).is_file()


def resolve_grade(grade: str | Path | ImuGrade) -> ImuGrade:
    """An ImuGrade from a grade, a preset name (``grades.GRADES``) or a YAML grade file."""
    if isinstance(grade, ImuGrade):
        return grade
    name = str(grade)
    if name in GRADES:
        return GRADES[name]
    if is_grade_file(name):
        return load_grade(name)
    raise CoreError(f"unknown IMU grade {name!r}: a preset ({', '.join(GRADES)}) or a YAML "
                    "grade file (docs/ins3d.md)")


def grade_thresholds(grade: ImuGrade, duration_s: float | None = None) -> dict[str, float]:
    """The GLR thresholds of a grade for a flight of ``duration_s``: a preset's
    (``glr3d.thresholds_for``), or a CustomGrade's raised by the same length growth."""
    if not isinstance(grade, CustomGrade) or not grade.thresholds:
        return thresholds_for(grade.name, duration_s)
    return at_length(dict(grade.thresholds), duration_s)


def at_length(thresholds: dict[str, float], duration_s: float | None) -> dict[str, float]:
    """Thresholds given for a flight of ``glr3d.CALIBRATED_LENGTH_S``, for a flight of
    ``duration_s`` (raised by ``glr3d.length_growth`` when longer)."""
    growth = length_growth(duration_s)
    return {k: v + growth.get(k, 0.0) for k, v in thresholds.items()}


#: the first line of the comment ``with_thresholds`` writes above the thresholds it sets
CALIBRATED_MARK = "# GLR thresholds calibrated by `flight-fdi calibrate`"


def with_thresholds(text: str, thresholds: dict[str, float], calibration: dict,
                    episode_probability: float | None = None) -> str:
    """A grade file's ``text`` with its ``thresholds`` (and an earlier calibration: its comment
    and ``calibration`` record) replaced by these, under a comment saying how they were made
    (``calibration``: flights, seeds, duration_s, profiles, target, exceeded, rate, interval95,
    date, ``seed`` for the seed method, ``rule`` / ``shares`` / ``growth`` for the budget --
    ``eval.calibrate3d.Calibration.metadata``) and, when given, the seed method's
    ``seed_episode_probability``. Thresholds per kind only are written as one mapping line,
    with per-hypothesis ones as a block (a key a line). The rest of the file, comments
    included, is kept."""
    ours = ("thresholds:", "calibration:", "seed_episode_probability:", CALIBRATED_MARK,
            "# calibration ")
    kept, skip = [], False
    for line in text.splitlines():
        if line[:1] not in (" ", "\t", ""):     # a top-level line: a key or a comment
            skip = line.startswith(ours)      # (a block's indented and blank lines follow it)
        if not skip:
            kept.append(line)
    while kept and not kept[-1].strip():
        kept.pop()
    c = calibration
    lo, hi = c["interval95"]
    note = [CALIBRATED_MARK + f" on {c['date']}:",
            f"# calibration flights: {c['flights']} nominal of {c['duration_s']:g} s "
            f"({', '.join(c['profiles'])}), seeds {c['seeds'][0]}-{c['seeds'][1]};",
            f"# calibration target: false isolation {100 * c['target']:g} % per flight;",
            f"# calibration result: {c['exceeded']} of {c['flights']} flights above a threshold "
            f"({100 * c['rate']:.1f} %, 95 % interval {100 * lo:.1f}-{100 * hi:.1f} %)"]
    if c.get("rule") == "per_hypothesis":
        sh = c["shares"]
        note.append(f"# calibration rule: per hypothesis, {100 * sh['hypothesis']:.3g} % of "
                    f"flights each, outliers {100 * sh['outliers']:.3g} % (kinds: fall-back)")
    keys = (*KINDS, *(h for h in PER_HYPOTHESIS if h in thresholds))
    if len(keys) > len(KINDS):          # per hypothesis too: a block, one key a line
        thr = "".join(f"\n  {k}: {float(thresholds[k]):.2f}" for k in keys)
    else:
        thr = " {" + ", ".join(f"{k}: {float(thresholds[k]):.2f}" for k in keys) + "}"
    seed = []
    if episode_probability is not None:
        sd = c.get("seed", {})
        p = float(episode_probability)
        note.append(f"# calibration seed method: episode probability {p:.3g}"
                    + (f", {sd['declared']} of {c['flights']} flights declared (with the "
                       f"default {sd['default']:g}: {sd['declared_default']})"
                       if sd else ""))
        seed = [f"seed_episode_probability: {p:.3e}"]
    return "\n".join(kept + note + [f"thresholds:{thr}"] + seed
                     + [f"calibration: {_yaml_json(c)}"]) + "\n"


def _yaml_json(record: dict) -> str:
    """``record`` as JSON whose numbers YAML 1.1 also reads as numbers (1e-06 -> 1.0e-06: PyYAML
    takes an exponent without a dot for a string)."""
    import json

    return re.sub(r"(?<=[\s\[:,])(-?\d+)e([-+]\d+)", r"\1.0e\2", json.dumps(record))


__all__ = ["CALIBRATED_MARK", "CustomGrade", "KEYS", "KINDS", "at_length", "diagnosis_config_of",
           "grade_from_dict",
           "grade_thresholds", "is_grade_file", "load_grade", "resolve_grade",
           "signature_error_of", "with_thresholds"]
