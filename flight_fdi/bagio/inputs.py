"""The input contract of the analysis: which topics carry the INS and reference velocities, in
which message types and frames, and what happens to every sample that is not used.

* Topics: ``InputSpec.ins_topic`` and one or more ``reference_topics`` (redundant references are
  merged: samples with the same header stamp become one information-weighted sample).
* Types, for either input: geometry_msgs/TwistStamped (no covariance: the model's R),
  geometry_msgs/TwistWithCovarianceStamped, nav_msgs/Odometry. **Odometry**: REP 105 puts its
  twist in ``child_frame_id`` (the body); it is rotated into ``header.frame_id`` (the
  navigation frame) by ``pose.pose.orientation`` (the covariance as R C R^T). With an empty
  ``child_frame_id``, or one equal to ``header.frame_id``, or ``odometry_twist_frame: header``
  (drivers that publish the navigation-frame velocity there), it is used as it is.
* Frames: ``nav_frame`` ``enu`` (REP 103: x east, y north, z up) or ``ned`` (x north, y east,
  z down) maps the channel names (east/north) to the twist components.
* Stamps: header stamps, sorted when the receive order is merely shuffled (a message at most
  ``reorder_window_s`` older than the newest one so far); an older one is dropped as
  ``out_of_order`` (a clock jumping back).
* Every message that is not used is counted by reason (``DROP_REASONS``) per topic.

A YAML *input profile* (``--input-profile FILE``) may hold all of it::

    ins_topic: /xsens/twist
    reference_topics: [/gps/vel]
    nav_frame: enu
    channel: x
    odometry_twist_frame: child
    reorder_window_s: 10.0
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from . import cdr
from .errors import BagError

SUPPORTED_TYPES = (cdr.TWIST_STAMPED, cdr.TWIST_COV_STAMPED, cdr.ODOMETRY)
#: every reason a sample is not used (or, the last one, used with the model's R instead)
DROP_REASONS = ("non_finite", "zero_stamp", "duplicate_stamp", "out_of_order",
                "outside_ins_record", "ins_gap", "invalid_covariance_replaced")
INS_REASONS = DROP_REASONS[:4]
NAV_FRAMES = {"enu": {"east": "x", "north": "y", "up": "z"},
              "ned": {"north": "x", "east": "y", "down": "z"}}
DEFAULT_INS_TOPIC = "/ins/velocity"
DEFAULT_REFERENCE_TOPIC = "/reference/velocity"


@dataclass(frozen=True)
class InputSpec:
    """Where and how the analysis reads its inputs (module docstring)."""

    ins_topic: str = DEFAULT_INS_TOPIC
    reference_topics: tuple = (DEFAULT_REFERENCE_TOPIC,)
    channel: str = "x"
    nav_frame: str = "enu"
    odometry_twist_frame: str = "child"
    reorder_window_s: float = 10.0

    def __post_init__(self) -> None:
        refs = self.reference_topics
        if isinstance(refs, str):
            refs = (refs,)
        object.__setattr__(self, "reference_topics", tuple(refs))
        for t in (self.ins_topic, *self.reference_topics):
            if not isinstance(t, str) or not t.strip():
                raise BagError(f"input: a topic name must be a non-empty string, got {t!r}")
        if not self.reference_topics:
            raise BagError("input: at least one reference topic is needed")
        if self.ins_topic in self.reference_topics:
            raise BagError(f"input: {self.ins_topic} cannot be both the INS and a reference")
        if len(set(self.reference_topics)) != len(self.reference_topics):
            raise BagError(f"input: reference topics repeat: {list(self.reference_topics)}")
        if self.nav_frame not in NAV_FRAMES:
            raise BagError(f"input: nav_frame must be enu or ned, got {self.nav_frame!r}")
        if self.odometry_twist_frame not in ("child", "header"):
            raise BagError("input: odometry_twist_frame must be child or header, got "
                           f"{self.odometry_twist_frame!r}")
        w = self.reorder_window_s
        if isinstance(w, bool) or not isinstance(w, (int, float)) or not math.isfinite(w) \
                or w < 0:
            raise BagError(f"input: reorder_window_s must be a number >= 0, got {w!r}")
        self.component  # validates the channel

    @property
    def component(self) -> str:
        """The twist component (x, y) of ``channel`` (x / y or a direction of nav_frame)."""
        names = NAV_FRAMES[self.nav_frame]
        c = names.get(self.channel, self.channel)
        if c not in ("x", "y"):
            allowed = ", ".join(["x", "y"] + [k for k, v in names.items() if v in "xy"])
            raise BagError(f"input: channel must be one of {allowed} ({self.nav_frame}), got "
                           f"{self.channel!r}")
        return c

    @property
    def axis_name(self) -> str:
        return {v: k for k, v in NAV_FRAMES[self.nav_frame].items()}[self.component]

    def describe(self) -> dict:
        return {"ins_topic": self.ins_topic, "reference_topics": list(self.reference_topics),
                "channel": self.component, "axis_name": self.axis_name,
                "nav_frame": self.nav_frame, "odometry_twist_frame": self.odometry_twist_frame,
                "reorder_window_s": float(self.reorder_window_s)}


def load_profile(path: str | Path) -> dict:
    """The settings of an input profile YAML file (keys: the InputSpec fields, and
    ``reference_topic`` for one reference). BagError naming the file on any problem."""
    import yaml

    p = Path(path)
    try:
        doc = yaml.safe_load(p.read_text(encoding="utf-8"))
    except OSError as exc:
        raise BagError(f"input profile {p}: {exc.strerror or exc}") from None
    except yaml.YAMLError as exc:
        raise BagError(f"input profile {p} is not valid YAML: "
                       f"{str(exc).splitlines()[0]}") from None
    if not isinstance(doc, dict):
        raise BagError(f"input profile {p}: expected a mapping of settings")
    known = {f.name for f in fields(InputSpec)}
    out = {}
    for k, v in doc.items():
        if k == "reference_topic":
            k, v = "reference_topics", [v]
        if k not in known:
            raise BagError(f"input profile {p}: unknown key {k!r} (known: "
                           f"{', '.join(sorted(known | {'reference_topic'}))})")
        out[k] = tuple(v) if k == "reference_topics" and isinstance(v, list) else v
    return out


def make_spec(profile: str | Path | None = None, **given: Any) -> InputSpec:
    """InputSpec from a profile file and explicit settings (None = not given); explicit
    settings win over the profile, the profile over the defaults."""
    values = load_profile(profile) if profile else {}
    values.update({k: v for k, v in given.items() if v is not None and v != []})
    if isinstance(values.get("reference_topics"), list):
        values["reference_topics"] = tuple(values["reference_topics"])
    return InputSpec(**values)


# --------------------------------------------------------------------------- one topic

@dataclass
class Series:
    """The usable samples of one topic (header stamps sorted) and what was dropped."""

    topic: str
    msgtype: str
    stamp: np.ndarray          # (K,) int64 ns
    v: np.ndarray              # (K,) m/s
    r: np.ndarray              # (K,) m^2/s^2, NaN: model R (none or invalid)
    messages: int
    dropped: dict = field(default_factory=dict)
    reordered: int = 0
    frame: str = ""            # what was done about frames (Odometry)


def decode_topic(msgtype: str, payloads: cdr.Payloads, spec: InputSpec, what: str
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, str]:
    """(stamp_ns, velocity of the channel, its variance or None, frame note) of one topic."""
    col = "xyz".index(spec.component)
    if msgtype == cdr.TWIST_STAMPED:
        s, tw, _ = cdr.decode(msgtype, payloads, what=what, twist_cols=[col])
        return s, tw[:, 0], None, "twist in the navigation frame (header.frame_id)"
    if msgtype == cdr.TWIST_COV_STAMPED:
        s, tw, cov = cdr.decode(msgtype, payloads, what=what, twist_cols=[col],
                                cov_cols=[7 * col])
        return s, tw[:, 0], cov[:, 0], "twist in the navigation frame (header.frame_id)"
    s, vals, frame, child = cdr.decode_odometry(payloads, what=what)
    q, lin, cov = vals[:, :4], vals[:, 4:7], vals[:, 7:].reshape(-1, 3, 3)
    if spec.odometry_twist_frame == "header" or not child or child == frame:
        note = (f"Odometry twist taken as in the navigation frame '{frame}' "
                + ("(odometry_twist_frame: header)" if spec.odometry_twist_frame == "header"
                   else f"(child_frame_id {'empty' if not child else 'equals header.frame_id'})"))
        return s, lin[:, col], cov[:, col, col], note
    R = _rotation(q)
    v_nav = np.einsum("kij,kj->ki", R, lin)
    c_nav = np.einsum("ki,kij,kj->k", R[:, col, :], cov, R[:, col, :])
    bad = ~np.isfinite(q).all(axis=1) | ~(np.abs((q * q).sum(axis=1) - 1.0) <= 1e-3)
    v = v_nav[:, col].copy()
    v[bad] = np.nan  # no usable orientation: counted as non_finite
    note = (f"Odometry twist in child_frame_id '{child}' (REP 105) rotated into '{frame}' by "
            "pose.pose.orientation")
    return s, v, c_nav, note


def _rotation(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (body -> parent) of quaternions (x, y, z, w), (K, 3, 3)."""
    x, y, z, w = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def clean_series(topic: str, msgtype: str, stamp: np.ndarray, v: np.ndarray,
                 r: np.ndarray | None, window_s: float, frame: str = "") -> Series:
    """Drop and count: non-finite velocity, zero stamps, stamps more than ``window_s`` older
    than the newest before them (out_of_order), then sort by stamp (``reordered`` counts the
    messages that moved) and drop repeated stamps (duplicate_stamp; the first is kept)."""
    n = int(stamp.size)
    dropped = dict.fromkeys(INS_REASONS, 0)
    finite = np.isfinite(v)
    dropped["non_finite"] = int((~finite).sum())
    zero = finite & (stamp == 0)
    dropped["zero_stamp"] = int(zero.sum())
    idx = np.flatnonzero(finite & ~zero)
    s = stamp[idx]
    reordered = 0
    if s.size > 1 and np.any(s[1:] < s[:-1]):
        newest = np.maximum.accumulate(s)  # newest stamp up to and including each message
        late = newest - s > int(round(window_s * 1e9))
        dropped["out_of_order"] = int(late.sum())
        idx, s = idx[~late], s[~late]
        order = np.argsort(s, kind="stable")
        reordered = int(np.count_nonzero(order != np.arange(order.size)))
        idx, s = idx[order], s[order]
    if s.size > 1:
        dup = np.concatenate([[False], s[1:] == s[:-1]])
        dropped["duplicate_stamp"] = int(dup.sum())
        idx, s = idx[~dup], s[~dup]
    rr = np.full(idx.size, np.nan) if r is None else np.asarray(r, dtype=float)[idx]
    return Series(topic, msgtype, s, np.ascontiguousarray(v[idx]), rr, n, dropped, reordered,
                  frame)


def merge_references(series: list[Series]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One reference series from several: all samples by stamp; samples of different topics
    with the same stamp become one, information-weighted (v = sum(v/r) / sum(1/r),
    r = 1 / sum(1/r); a plain mean with unknown r when any r of the group is unknown)."""
    if len(series) == 1:
        s = series[0]
        return s.stamp, s.v, s.r
    stamp = np.concatenate([s.stamp for s in series])
    v = np.concatenate([s.v for s in series])
    r = np.concatenate([s.r for s in series])
    uniq, inv = np.unique(stamp, return_inverse=True)
    inv = inv.reshape(-1)
    good_r = np.isfinite(r) & (r > 0)
    info = np.where(good_r, 1.0 / np.where(good_r, r, 1.0), 0.0)
    count = np.bincount(inv, minlength=uniq.size)
    n_bad = np.bincount(inv, weights=(~good_r).astype(float), minlength=uniq.size)
    sum_i = np.bincount(inv, weights=info, minlength=uniq.size)
    sum_iv = np.bincount(inv, weights=info * v, minlength=uniq.size)
    mean_v = np.bincount(inv, weights=v, minlength=uniq.size) / count
    weighted = n_bad == 0
    v_out = np.where(weighted, sum_iv / np.where(weighted, sum_i, 1.0), mean_v)
    r_out = np.where(weighted, 1.0 / np.where(weighted, sum_i, 1.0), np.nan)
    return uniq, v_out, r_out


def input_section(ins: Series, refs: list[Series], t_ins_ns: np.ndarray,
                  t_ref_ns: np.ndarray, aligned: np.ndarray) -> dict:
    """``input`` of a result: per topic its role, type, messages, samples used and the counts
    of every reason in ``DROP_REASONS`` (0 where it did not occur), ``reordered`` and the frame
    note. ``t_ref_ns`` / ``aligned``: the (merged) reference stamps and which of them the
    analysis could align with the INS (core.align)."""
    out = {}
    used_ins = int(ins.stamp.size)
    out[ins.topic] = _topic_entry("ins", ins, used_ins, INS_REASONS)
    outside = (t_ref_ns < t_ins_ns[0]) | (t_ref_ns > t_ins_ns[-1])
    for s in refs:
        pos = np.searchsorted(t_ref_ns, s.stamp)
        ok = aligned[pos]
        d = dict(s.dropped)
        d["outside_ins_record"] = int((~ok & outside[pos]).sum())
        d["ins_gap"] = int((~ok & ~outside[pos]).sum())
        d["invalid_covariance_replaced"] = int((ok & ~(np.isfinite(s.r) & (s.r > 0))).sum()) \
            if s.msgtype != cdr.TWIST_STAMPED else 0
        entry = _topic_entry("reference", s, int(ok.sum()), DROP_REASONS)
        entry["dropped"] = {k: int(d.get(k, 0)) for k in DROP_REASONS}
        out[s.topic] = entry
    return out


def _topic_entry(role: str, s: Series, used: int, reasons: tuple) -> dict:
    return {"role": role, "type": s.msgtype, "messages": int(s.messages), "used": used,
            "dropped": {k: int(s.dropped.get(k, 0)) for k in reasons},
            "reordered": int(s.reordered), "frame": s.frame,
            "covariance": "model R (TwistStamped has none)" if s.msgtype == cdr.TWIST_STAMPED
            else "message"}


#: the words of ``warnings`` for each reason of ``DROP_REASONS``
REASON_TEXT = {
    "non_finite": "non-finite velocity (dropped)",
    "zero_stamp": "header stamp 0 (dropped)",
    "duplicate_stamp": "repeated header stamp (dropped; the first kept)",
    "out_of_order": "header stamp older than the reorder window (dropped; a clock jumping "
                    "back? raise reorder_window_s to sort them)",
    "outside_ins_record": "outside the INS record (not used)",
    "ins_gap": "in an INS gap longer than max_gap_s (not used)",
    "invalid_covariance_replaced": "invalid covariance (used with the model's R)"}


def warnings(section: dict, texts: dict | None = None) -> list[str]:
    """One line per topic and reason that occurred (and per reordered topic), in the words of
    ``REASON_TEXT`` with ``texts`` (another input's reasons, e.g. the 3-D model's
    ``bagio.ins3d_input.REASON_TEXT3D``) over them; a reason without words is named as it is."""
    what = {**REASON_TEXT, **(texts or {})}
    lines = []
    for topic, e in section.items():
        if not isinstance(e, dict) or "dropped" not in e:
            continue
        for k, n in e["dropped"].items():
            if n:
                lines.append(f"warning: {topic}: {n} of {e['messages']} messages: "
                             f"{what.get(k, k.replace('_', ' '))}")
        if e.get("reordered"):
            lines.append(f"warning: {topic}: {e['reordered']} messages arrived out of header-"
                         "stamp order and were sorted by header stamp")
    return lines
