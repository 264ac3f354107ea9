"""Triple-redundant IMU voter (seed 002, SPEC section 4) as a ROS 2 node.

Inputs
    ``imu_topics`` (default ``/imu1/data``, ``/imu2/data``, ``/imu3/data``; sensor_msgs/Imu):
    three co-mounted IMUs. QoS ``input_qos``: ``sensor_data`` (best effort) or ``reliable``.

Outputs
    ``fdi/vote`` (flight_fdi_msgs/VoteStatus): the vote of every quantity (gyro x/y/z, accel
    x/y/z, as the threshold table lists them): window means of x1 = P1 - P2, x2 = P2 - P3,
    x3 = P1 - P3, the bounds in force, eps, their sum, the status, the isolated IMU, the selected
    IMU. Published every ``status_every`` decisions and whenever a status, an isolation or the
    selection changes.
    ``imu/voted`` (sensor_msgs/Imu): the selected IMU's message, unchanged (its frame_id names
    the IMU), once per matched triple.
    ``/diagnostics`` every ``diagnostics_period_s``.

Time alignment
    The three streams are matched by header stamp: the oldest waiting sample of each IMU form a
    triple when their stamps lie within ``match_tolerance_s``; a sample older than the newest
    head minus the tolerance has no partner (counted ``unmatched_imuK``) and a sample that waited
    more than ``max_wait_s`` of stamp time (an IMU is late or silent) expires (counted too).
    Unmatched samples of the selected IMU are still forwarded on ``imu/voted`` (not voted), so
    the output keeps flowing when another IMU is silent.

Voting
    The matched triples go through the voter engine shared with ``flight-fdi vote``
    (flight_fdi.core.voter_core.VoterCore, one triple per call): with a table calibrated on
    recordings (its ``model`` section) IMU2 and IMU3 are first moved onto IMU1's time (the
    table's / ``time_offsets_s``'s offsets, or estimated over the learning phase) and into IMU1's
    axes (mounting), the pair differences are prefiltered, their window means (the table's N
    samples, growing until N exist) minus each pair's offset learnt in the first ``learn_s``
    seconds are compared with the table's bounds at the flight time t = stamp - stamp of the
    first triple (IMU1's stamps, exact integer nanoseconds); no decision while learning, and
    decisions lag the input by the largest time offset. With a table of the simulator (no model)
    it is the seed's statistic exactly. eps_k = 1 when the statistic of x_k is inside its bounds,
    and the seed's truth table gives the verdict (flight_fdi.core.voting.vote_array).

Selection (sticky)
    A single-fault verdict naming IMU k on a quantity for the larger of ``confirm_decisions``
    decisions and ``confirm_s`` seconds (default 1 s, chosen on the real recordings,
    docs/voter_real.md) **isolates** IMU k on that quantity. The selected IMU is the first of
    IMU1, IMU2, IMU3 isolated on no quantity (which is the truth table's choice for every single
    fault); a multiple fault isolates nothing and keeps the selection. With ``sticky`` (default)
    an isolation is latched: it is released only after ``release_after_windows`` complete
    windows (N decisions each) of healthy votes (sum 3) in a row on that quantity; 0 never
    releases it (until restart). So the output never flaps. A confirmed single fault naming
    another IMU on the same quantity replaces the isolation. Without ``sticky`` a healthy or
    marginal vote clears the isolation at once. An IMU whose newest stamp lags the newest stamp
    of the others by more than ``stale_after_s`` (silent) is not selected either while another
    IMU is live.

Bad input never stops the node: non-finite values, values too large for the window statistic
(|value| > max float / (4 N): a window of pair differences could overflow float64), duplicate and
out-of-order stamps are dropped and counted per IMU (``dropped_imuK_<reason>``: ``nonfinite``,
``out_of_range``, ``duplicate``, ``out_of_order``); a stamp going back by more than
``time_jump_reset_s`` restarts the voter (windows, flight time, learning; isolations are kept).
Silent and never-arriving inputs are reported in ``/diagnostics``.

Parameters: ``VOTER_PARAMS`` below (documented in ``config/voter.yaml``). A missing or invalid
threshold table stops the node at start-up with a ParameterError naming ``thresholds_file``.
"""
from __future__ import annotations

import sys
from collections import deque
from typing import Any

import numpy as np
from rclpy.exceptions import NameValidationException
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.validate_topic_name import validate_topic_name

from ..core.errors import CoreError
from ..core.voter_core import DEFAULT_CONFIRM_S, DEFAULT_RELEASE_WINDOWS, VoterCore, VoterModel, \
    select
from ..core.voting import QUANTITIES, ThresholdTable, load_table
from . import convert
from . import diagnostics as diag
from . import voter_diagnostics
from .errors import ParameterError
from .params import ParamSpec, declare_parameters, fail
from .setup import destroyed_on_failure

NODE_NAME = "voter_node"
PARAMS_FILE_HEADER = """\
Parameters of voter_node (the triple-redundant IMU voter of seed 002).
Use: ros2 run flight_fdi voter_node --ros-args --params-file config/voter.yaml \\
       -p thresholds_file:=thresholds.json
The threshold table comes from: flight-fdi voter-calibrate thresholds.json
Every parameter is listed at its default; changes need a restart. An invalid value (or a missing /
corrupt threshold table) stops the node at start-up with a message naming the parameter.
Generated by: python -m flight_fdi.nodes.params flight_fdi.nodes.voter_node"""

VOTER_PARAMS = (
    ParamSpec("thresholds_file", "string", "",
              "Threshold table written by flight-fdi voter-calibrate (JSON); required"),
    ParamSpec("imu_topics", "string_array", ["/imu1/data", "/imu2/data", "/imu3/data"],
              "The three IMU inputs (sensor_msgs/Imu), IMU1 first", non_empty=True),
    ParamSpec("input_qos", "string", "sensor_data",
              "QoS of the inputs: sensor_data (best effort) or reliable",
              choices=("sensor_data", "reliable")),
    ParamSpec("input_queue_depth", "int", 200, "History depth of the input subscriptions",
              "messages", min=1, max=100000),
    ParamSpec("match_tolerance_s", "double", 0.002,
              "Largest stamp difference of the three samples of a triple", "s", min=0.0,
              max=1.0, min_exclusive=True),
    ParamSpec("max_wait_s", "double", 0.1,
              "How long (in stamp time) a sample waits for its partners before it expires", "s",
              min=0.0, max=60.0, min_exclusive=True),
    ParamSpec("sticky", "bool", True,
              "Latch isolations (release only after release_after_windows healthy windows)"),
    ParamSpec("release_after_windows", "int", DEFAULT_RELEASE_WINDOWS,
              "Complete windows of healthy votes in a row that release a latched isolation "
              "(0: never)", "windows", min=0, max=1000000),
    ParamSpec("confirm_decisions", "int", 1,
              "Consecutive single-fault decisions naming the same IMU that isolate it (the "
              "larger of this and confirm_s counts)", "decisions", min=1, max=1000000),
    ParamSpec("confirm_s", "double", DEFAULT_CONFIRM_S,
              "A single fault naming the same IMU must persist this long to isolate it (0: "
              "confirm_decisions alone)", "s", min=0.0, max=3600.0),
    ParamSpec("time_offsets_s", "double_array", [0.0, 0.0, 0.0],
              "Time offsets of IMU1..IMU3 against IMU1 (first 0); all 0: the threshold "
              "table's (estimated at start-up when the table's model says so)", "s",
              min=-10.0, max=10.0),
    ParamSpec("status_every", "int", 1,
              "Publish fdi/vote every this many decisions (and on every change)", "decisions",
              min=1, max=1000000),
    ParamSpec("time_jump_reset_s", "double", 1.0,
              "A stamp going backwards by more than this restarts the voter (smaller steps back "
              "are dropped as out of order)", "s", min=0.0, min_exclusive=True),
    ParamSpec("diagnostics_period_s", "double", 1.0, "Period of /diagnostics", "s",
              min=0.0, max=3600.0, min_exclusive=True),
    ParamSpec("stale_after_s", "double", 0.5,
              "An input with no message for longer than this is reported stale (WARN) and an "
              "IMU this far behind the others is not selected", "s", min=0.0,
              min_exclusive=True),
    ParamSpec("rate_window_s", "double", 5.0, "Window of the input rate estimate", "s",
              min=0.0, max=3600.0, min_exclusive=True),
)


def validate(values: dict[str, Any]) -> None:
    """Cross-field checks (the table is loaded in the node)."""
    if not values["thresholds_file"].strip():
        fail("thresholds_file", values["thresholds_file"],
             "the path of a threshold table written by flight-fdi voter-calibrate")
    topics = values["imu_topics"]
    if len(topics) != 3:
        fail("imu_topics", topics, "exactly three topics (IMU1, IMU2, IMU3)")
    if values["max_wait_s"] <= values["match_tolerance_s"]:
        fail("max_wait_s", values["max_wait_s"], "more than match_tolerance_s")
    tau = values["time_offsets_s"]
    if len(tau) != 3 or tau[0] != 0.0:
        fail("time_offsets_s", tau, "three offsets [0, tau2, tau3] in seconds")


def load_model(table: ThresholdTable, path: str) -> VoterModel:
    """The table's real-sensor model, or ParameterError naming thresholds_file."""
    try:
        return VoterModel.from_table(table)
    except CoreError as exc:
        raise ParameterError(f"invalid parameter 'thresholds_file': got {path!r}; {exc}") \
            from None


def load_thresholds(path: str) -> ThresholdTable:
    """The threshold table, or ParameterError naming thresholds_file."""
    try:
        return load_table(path)
    except CoreError as exc:
        raise ParameterError(f"invalid parameter 'thresholds_file': got {path!r}; {exc}") \
            from None


def input_qos(kind: str, depth: int) -> QoSProfile:
    reliability = (ReliabilityPolicy.BEST_EFFORT if kind == "sensor_data"
                   else ReliabilityPolicy.RELIABLE)
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=reliability,
                      durability=DurabilityPolicy.VOLATILE)


def imu_values(msg: Any) -> np.ndarray:
    """sensor_msgs/Imu -> (6,) gyro x/y/z [rad/s], accel x/y/z [m/s^2] (QUANTITIES order)."""
    w, a = msg.angular_velocity, msg.linear_acceleration
    return np.array([w.x, w.y, w.z, a.x, a.y, a.z], dtype=float)


class VoterNode(Node):
    """The voter node (see the module docstring).

    ``VoterNode(context=..., parameter_overrides=[...])`` builds it in-process; invalid
    parameters (or threshold table) raise ParameterError."""

    def __init__(self, node_name: str = NODE_NAME, **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        with destroyed_on_failure(self):
            self._setup()

    # ------------------------------------------------------------------ set-up
    def _setup(self) -> None:
        p = self.p = declare_parameters(self, VOTER_PARAMS, validator=validate)
        self.table = load_thresholds(p["thresholds_file"])
        self.quantities = list(self.table.quantities)
        self._qi = np.array([QUANTITIES.index(q) for q in self.quantities])
        Q = len(self.quantities)
        self.window = int(self.table.window)
        self.model = load_model(self.table, p["thresholds_file"])
        self.confirm = max(p["confirm_decisions"],
                           int(np.ceil(p["confirm_s"] * self.table.rate_hz - 1e-9)))
        tau = p["time_offsets_s"]
        self._tau = None if not any(tau) else list(tau)
        self.core = self._new_core()
        # a pair difference is at most 2 max|v|; a window sum of N of them must stay finite
        self._max_abs = sys.float_info.max / (4 * self.window)

        names = []
        for topic in p["imu_topics"]:
            try:
                validate_topic_name(topic)
                names.append(self.resolve_topic_name(topic))
            except NameValidationException as exc:
                fail("imu_topics", p["imu_topics"],
                     f"valid ROS topic names ({str(exc).splitlines()[0]})")
            except RuntimeError as exc:
                fail("imu_topics", p["imu_topics"], f"valid ROS topic names ({exc})")
        if len(set(names)) != 3:
            fail("imu_topics", p["imu_topics"], f"three different topics (they resolve to "
                 f"{', '.join(names)})")
        self.topics = names

        from flight_fdi_msgs.msg import VoteStatus
        from sensor_msgs.msg import Imu

        self._VoteStatus = VoteStatus
        qos = input_qos(p["input_qos"], p["input_queue_depth"])
        for k, topic in enumerate(self.topics):
            self.create_subscription(Imu, topic, lambda msg, k=k: self._on_imu(k, msg), qos)
        out_qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                             reliability=ReliabilityPolicy.RELIABLE)
        self.pub_vote = self.create_publisher(VoteStatus, "fdi/vote", out_qos)
        self.pub_voted = self.create_publisher(Imu, "imu/voted", out_qos)

        names3 = [f"imu{k + 1}" for k in range(3)]
        counts = ["matched_triples", "decisions", "voted_published", "unvoted_published",
                  "selection_switches", "isolations", "releases", "resets"]
        for nm in names3:
            counts += [f"received_{nm}", f"unmatched_{nm}", f"dropped_{nm}_nonfinite",
                       f"dropped_{nm}_out_of_range",
                       f"dropped_{nm}_duplicate", f"dropped_{nm}_out_of_order"]
        self.counters = diag.Counters(counts)
        self._queues: list[deque] = [deque() for _ in range(3)]
        self._last_t: list[float | None] = [None, None, None]
        self._t0: int | None = None  # ns stamp of the first triple
        self._lower, self._upper = self.table.lower_grid[0], self.table.upper_grid[0]
        self._stamps: deque = deque()   # (triple index, header stamp) awaiting their decision
        self._n_triples = 0

        self.selected = 1
        self._last_status = np.full(Q, -1, dtype=np.int8)
        self.last_vote: dict[str, Any] | None = None
        self._since_status = 0
        self._triple_rate = diag.RateMeter(self.p["rate_window_s"])

        self.inputs = diag.InputMonitor(self._now, self.topics, window_s=p["rate_window_s"],
                                        stale_after_s=p["stale_after_s"])
        self.diagnostics = diag.DiagnosticsTimer(self, p["diagnostics_period_s"],
                                                 self.diagnostic_statuses)
        self.get_logger().info(
            f"voting {', '.join(self.quantities)} of {', '.join(self.topics)} with "
            f"{p['thresholds_file']} (window {self.window}, alpha {self.table.alpha:g}, "
            f"calibrated at {self.table.rate_hz:g} Hz); sticky={p['sticky']}, confirm "
            f"{self.confirm} decisions, release after {p['release_after_windows']} windows")

    def _new_core(self, persistence=None) -> VoterCore:
        core = VoterCore(self.table, self.confirm, self.p["release_after_windows"],
                         self.p["sticky"], self._tau, self.model)
        if persistence is not None:
            core.persistence = persistence      # a restart keeps the isolations
        return core

    @property
    def latched(self) -> np.ndarray:
        """Isolated IMU per quantity (0: none)."""
        return np.array(self.core.persistence.isolated, dtype=np.int8)

    def _now(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    # ------------------------------------------------------------------ input
    def _on_imu(self, k: int, msg: Any) -> None:
        name = f"imu{k + 1}"
        self.inputs.seen(self.topics[k])
        self.counters.inc(f"received_{name}")
        stamp = msg.header.stamp
        t = convert.stamp_to_s(stamp)
        v = imu_values(msg)
        if not np.all(np.isfinite(v)):
            self._drop(f"{name}_nonfinite", f"{name} sample at t={t:.3f} s: non-finite values")
            return
        if np.any(np.abs(v) > self._max_abs):
            self._drop(f"{name}_out_of_range", f"{name} sample at t={t:.3f} s: a value beyond "
                       f"{self._max_abs:.3g} (the window statistic would overflow)")
            return
        last = self._last_t[k]
        if last is not None and t <= last:
            if t == last:
                self._drop(f"{name}_duplicate", f"{name} sample at t={t:.3f} s: duplicate stamp")
                return
            if last - t <= self.p["time_jump_reset_s"]:
                self._drop(f"{name}_out_of_order", f"{name} sample at t={t:.3f} s: older than "
                           f"the last one ({last:.3f} s)")
                return
            self._time_jump(t, last)
        self._last_t[k] = t
        self._queues[k].append((t, msg, v, stamp.sec * 1_000_000_000 + stamp.nanosec))
        self._match()

    def _drop(self, reason: str, detail: str) -> None:
        self.counters.inc("dropped_" + reason)
        self.get_logger().warning(f"dropped {detail}", throttle_duration_sec=5.0)

    def _time_jump(self, t: float, last: float) -> None:
        self.get_logger().warning(f"IMU time jumped back from {last:.3f} s to {t:.3f} s: voter "
                                  "restarted (windows and flight time; isolations kept)")
        self.counters.inc("resets")
        for k, q in enumerate(self._queues):
            self.counters.inc(f"unmatched_imu{k + 1}", len(q))
            q.clear()
        self._last_t = [None, None, None]
        self._t0 = None
        self._stamps.clear()
        self._n_triples = 0
        self.core = self._new_core(self.core.persistence)

    # ------------------------------------------------------------------ matching
    def _match(self) -> None:
        tol = self.p["match_tolerance_s"]
        qs = self._queues
        while qs[0] and qs[1] and qs[2]:
            heads = [q[0][0] for q in qs]
            newest = max(heads)
            if newest - min(heads) <= tol:
                triple = [q.popleft() for q in qs]
                self._decide(triple)
                continue
            for k in range(3):
                if heads[k] < newest - tol:  # its partners in the stream at `newest` are gone
                    self._unmatched(k, qs[k].popleft())
        # expiry: a sample waiting longer than max_wait_s (stamp time) for a silent IMU
        newest_t = max((t for t in self._last_t if t is not None), default=None)
        if newest_t is None:
            return
        limit = newest_t - self.p["max_wait_s"]
        for k, q in enumerate(qs):
            while q and q[0][0] < limit:
                self._unmatched(k, q.popleft())

    def _unmatched(self, k: int, sample: tuple) -> None:
        self.counters.inc(f"unmatched_imu{k + 1}")
        self._reselect(f"t={sample[0]:.3f} s")
        if self.selected == k + 1:
            self.pub_voted.publish(sample[1])
            self.counters.inc("unvoted_published")

    # ------------------------------------------------------------------ voting
    def _decide(self, triple: list[tuple]) -> None:
        t = triple[0][0]
        self.counters.inc("matched_triples")
        self._triple_rate.tick(t)
        ns = triple[0][3]
        if self._t0 is None:
            self._t0 = ns
        self._stamps.append((self._n_triples, triple[0][1].header.stamp))
        self._n_triples += 1
        P = np.stack([s[2] for s in triple], axis=1)                     # (6, 3 IMUs)
        d = self.core.push(np.array([ns]), P[None])
        changed = False
        for i in range(len(d)):
            changed |= self._decided(d, i)
        changed |= self._reselect(f"flight time {(ns - self._t0) * 1e-9:.3f} s")
        self.pub_voted.publish(triple[self.selected - 1][1])
        self.counters.inc("voted_published")
        if len(d) and (changed or self._since_status >= self.p["status_every"]):
            self._since_status = 0
            v = self.last_vote
            self.pub_vote.publish(self._vote_msg(v["stamp"], v["mean"], v["eps"], v["status"]))

    def _decided(self, d, i: int) -> bool:
        """Book one decision of the engine; True when a status or an isolation changed."""
        index = int(d.index[i])
        while self._stamps and self._stamps[0][0] < index:
            self._stamps.popleft()
        stamp = self._stamps[0][1] if self._stamps else None
        self.counters.inc("decisions")
        self._since_status += 1
        self._lower, self._upper = d.lower[i], d.upper[i]
        status = d.status[i]
        changed = bool(np.any(status != self._last_status))
        self._last_status = status.astype(np.int8)
        t_flight = float(d.t_flight[i])
        for te, q, old, new in d.events:
            if te != t_flight:
                continue
            changed = True
            if new:
                self.counters.inc("isolations")
                self.get_logger().warning(f"t={te:.3f} s: IMU{new} isolated on "
                                          f"{self.quantities[q]} (single fault by majority)")
            else:
                self.counters.inc("releases")
                self.get_logger().info(f"t={te:.3f} s: IMU{old} released on "
                                       f"{self.quantities[q]}")
        self.last_vote = {"t_flight": t_flight, "mean": d.deviation[i], "eps": d.eps[i],
                          "status": status, "faulty": d.faulty[i], "stamp": stamp}
        return changed

    def _stale_imus(self) -> set[int]:
        """IMUs (1..3) whose newest stamp lags the newest of all by more than stale_after_s."""
        known = [t for t in self._last_t if t is not None]
        if not known:
            return set()
        newest = max(known)
        lag = self.p["stale_after_s"]
        return {k + 1 for k, t in enumerate(self._last_t) if t is None or t < newest - lag}

    def _reselect(self, when: str) -> bool:
        """Apply the selection rule; log and count a switch. True when the selection changed."""
        before = self.selected
        stale = self._stale_imus()
        self.selected = select(self.core.persistence.isolated, before, stale)
        if self.selected == before:
            return False
        self.counters.inc("selection_switches")
        why = f"isolated: {self._isolated_text()}"
        if stale:
            why += f"; silent: {', '.join(f'IMU{k}' for k in sorted(stale))}"
        self.get_logger().warning(f"{when}: output switched from IMU{before} to "
                                  f"IMU{self.selected} ({why})")
        return True

    def _isolated_text(self) -> str:
        parts = [f"IMU{v} on {q}" for q, v in zip(self.quantities, self.latched) if v]
        return ", ".join(parts) or "none"

    def _vote_msg(self, stamp: Any, mean: np.ndarray, eps: np.ndarray, status: np.ndarray):
        isolated = self.latched.astype(np.uint8)
        msg = self._VoteStatus()
        msg.header = convert.header(stamp, "")
        msg.quantities = list(self.quantities)
        msg.pair_mean = mean.reshape(-1).tolist()
        msg.lower_bound = self._lower.reshape(-1).tolist()
        msg.upper_bound = self._upper.reshape(-1).tolist()
        msg.epsilon = eps.astype(np.uint8).reshape(-1).tolist()
        msg.epsilon_sum = eps.sum(axis=1).astype(np.uint8).tolist()
        msg.status = status.astype(np.uint8).tolist()
        msg.isolated_imu = isolated.tolist()
        msg.selected_imu = int(self.selected)
        msg.overall_status = int(status.max())
        return msg

    # ------------------------------------------------------------------ diagnostics
    def diagnostic_statuses(self) -> list:
        return voter_diagnostics.statuses(self)


def main(args: list[str] | None = None) -> int:
    """``ros2 run flight_fdi voter_node [--executor {events,single}] [--ros-args ...]``
    (EventsExecutor by default: the latency target); exit 1 on invalid parameters."""
    from .runner import run_node

    return run_node(VoterNode, NODE_NAME, args, default_executor="events")


if __name__ == "__main__":
    sys.exit(main())
