"""Diagnostics helpers shared by all flight_fdi nodes (``/diagnostics`` at 1 Hz).

API (stable; used by every node)::

    OK, WARN, ERROR, STALE                     DiagnosticStatus levels (bytes, as the message wants)
    level_name(level) -> "OK" | "WARN" | "ERROR" | "STALE"
    worst(levels) -> level                     the most severe (STALE counts as WARN-or-worse)
    format_value(v) -> str                     key-value text: floats %.6g, NaN -> "nan",
                                               None -> "never"
    make_status(name, level, message, values: Mapping[str, Any] | Iterable[(k, v)],
                hardware_id="") -> DiagnosticStatus
    make_array(stamp, statuses) -> DiagnosticArray        stamp: builtin_interfaces/Time
    update_freshness(since_s, stale_after_s) -> (level, message)   a filter channel's update age

    Counters(names=())            named event counts (received, fused, gated, rejected,
        .inc(name, n=1)           dropped_<reason> ...); unknown names start at 0
        [name] -> int, .get(name), .names(), .items(), .as_dict(), .total(prefix="dropped_")
        .key_values(prefix="") -> list[(key, str)]

    RateMeter(window_s=5.0)       events per second over a sliding window of the node's clock
        .tick(now_s)              (pass ``node.get_clock().now().nanoseconds * 1e-9`` so that
        .rate(now_s) -> float     sim time works); rate is 0.0 when no event in the window

    InputMonitor(clock_now, names, window_s=5.0, stale_after_s=2.0)
        for each named input: message count, rate and staleness (seconds since the last message
        on the node's clock; NaN when none yet)
        .seen(name)               call in the subscription callback
        .count(name) .rate(name) .age(name) -> float (NaN = never) .is_stale(name) -> bool
        .never_seen(name) -> bool
        .key_values() -> list[(key, str)]   "<name> rate_hz", "<name> age_s", "<name> count"
        .problems(clock_stalled_s=0.0) -> list[str]  "no messages on <name> yet",
                                  "<name> stale for 12.3 s" ...; while the node clock is stalled
                                  (``clock_stalled_s`` > 0) the ages are wall-clock ones

    DiagnosticsTimer(node, period_s, build, hardware_id="")   publishes
        ``build() -> list[DiagnosticStatus]`` on /diagnostics every ``period_s`` of the node's
        clock (also callable: .publish_now()). A steady-clock timer keeps publishing when the
        node's clock stops (use_sim_time and /clock silent): then a "<node>: clock" WARN status
        ("clock stalled for 12.3 s") is added. .clock_stalled_s() -> float (0.0 when running).

``clock_now`` is a zero-argument callable returning the current node time in seconds, e.g.
``lambda: node.get_clock().now().nanoseconds * 1e-9``.
"""
from __future__ import annotations

import math
import time
from collections import deque
from typing import Any, Callable, Iterable, Mapping

OK = b"\x00"
WARN = b"\x01"
ERROR = b"\x02"
STALE = b"\x03"
_NAMES = {OK: "OK", WARN: "WARN", ERROR: "ERROR", STALE: "STALE"}
_RANK = {OK: 0, STALE: 1, WARN: 2, ERROR: 3}


def level_name(level: bytes) -> str:
    return _NAMES.get(bytes(level), f"level {level!r}")


def worst(levels: Iterable[bytes]) -> bytes:
    """The most severe level of ``levels`` (OK when empty); ERROR > WARN > STALE > OK."""
    out = OK
    for lv in levels:
        if _RANK[bytes(lv)] > _RANK[out]:
            out = bytes(lv)
    return out


def format_value(value: Any) -> str:
    if value is None:
        return "never"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        return f"{value:.12g}"  # enough for stamps in seconds since 1970 to show ms
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(format_value(v) for v in value) + "]"
    return str(value)


def make_status(name: str, level: bytes, message: str,
                values: Mapping[str, Any] | Iterable[tuple[str, Any]] = (),
                hardware_id: str = ""):
    from diagnostic_msgs.msg import DiagnosticStatus, KeyValue

    items = values.items() if isinstance(values, Mapping) else values
    return DiagnosticStatus(
        level=bytes(level), name=name, message=message, hardware_id=hardware_id,
        values=[KeyValue(key=str(k), value=v if isinstance(v, str) else format_value(v))
                for k, v in items])


def update_freshness(since_s: float | None, stale_after_s: float) -> tuple[bytes, str]:
    """(level, message) of a filter channel from the time since its last update (None: never):
    WARN "no filter update yet" / "no filter update for 3.2 s", or OK "filtering"."""
    if since_s is None:
        return WARN, "no filter update yet"
    if since_s > stale_after_s:
        return WARN, f"no filter update for {since_s:.1f} s"
    return OK, "filtering"


def make_array(stamp, statuses: Iterable[Any]):
    from diagnostic_msgs.msg import DiagnosticArray
    from std_msgs.msg import Header

    return DiagnosticArray(header=Header(stamp=stamp), status=list(statuses))


class Counters:
    """Named event counts, in first-use order (names given up front are reported even at 0)."""

    def __init__(self, names: Iterable[str] = ()) -> None:
        self._c: dict[str, int] = {n: 0 for n in names}

    def inc(self, name: str, n: int = 1) -> int:
        self._c[name] = self._c.get(name, 0) + n
        return self._c[name]

    def __getitem__(self, name: str) -> int:
        return self._c.get(name, 0)

    get = __getitem__

    def names(self) -> list[str]:
        return list(self._c)

    def items(self) -> list[tuple[str, int]]:
        return list(self._c.items())

    def as_dict(self) -> dict[str, int]:
        return dict(self._c)

    def total(self, prefix: str = "dropped_") -> int:
        return sum(v for k, v in self._c.items() if k.startswith(prefix))

    def key_values(self, prefix: str = "") -> list[tuple[str, str]]:
        return [(prefix + k, str(v)) for k, v in self._c.items()]


class RateMeter:
    """Events per second over the last ``window_s`` seconds (times from the caller's clock).

    The rate is (events in the window) / (window length actually covered), where the covered
    length is the window, or the time since the first event if that is shorter, so that a fresh
    10 Hz stream reads ~10 Hz after its second message rather than ramping up over the window.
    """

    def __init__(self, window_s: float = 5.0) -> None:
        if not (window_s > 0 and math.isfinite(window_s)):
            raise ValueError(f"RateMeter: window must be > 0 s, got {window_s!r}")
        self.window_s = float(window_s)
        self._t: deque[float] = deque()
        self._first: float | None = None

    def tick(self, now_s: float) -> None:
        if self._t and now_s < self._t[-1]:  # clock went backwards (sim time reset): start over
            self._t.clear()
            self._first = None
        if self._first is None:
            self._first = now_s
        self._t.append(now_s)
        self._trim(now_s)

    def _trim(self, now_s: float) -> None:
        lo = now_s - self.window_s
        while self._t and self._t[0] < lo:
            self._t.popleft()

    def rate(self, now_s: float) -> float:
        self._trim(now_s)
        if self._first is None or not self._t:
            return 0.0
        if now_s - self._first >= self.window_s:
            return len(self._t) / self.window_s
        # history shorter than the window: mean rate between the first and the last event
        span = self._t[-1] - self._t[0]
        return (len(self._t) - 1) / span if span > 0.0 else 0.0


class InputMonitor:
    """Per-input message count, rate and staleness, on the node's clock."""

    def __init__(self, clock_now: Callable[[], float], names: Iterable[str],
                 window_s: float = 5.0, stale_after_s: float = 2.0) -> None:
        self._now = clock_now
        self.stale_after_s = float(stale_after_s)
        self._names = list(names)
        self._count = {n: 0 for n in self._names}
        self._last: dict[str, float | None] = {n: None for n in self._names}
        self._wall: dict[str, float | None] = {n: None for n in self._names}
        self._rate = {n: RateMeter(window_s) for n in self._names}

    @property
    def names(self) -> list[str]:
        return list(self._names)

    def seen(self, name: str) -> None:
        now = self._now()
        self._count[name] += 1
        self._last[name] = now
        self._wall[name] = time.monotonic()
        self._rate[name].tick(now)

    def count(self, name: str) -> int:
        return self._count[name]

    def never_seen(self, name: str) -> bool:
        return self._last[name] is None

    def age(self, name: str) -> float:
        last = self._last[name]
        return math.nan if last is None else max(0.0, self._now() - last)

    def rate(self, name: str) -> float:
        return self._rate[name].rate(self._now())

    def is_stale(self, name: str) -> bool:
        """True when no message yet, or none for more than ``stale_after_s``."""
        age = self.age(name)
        return math.isnan(age) or age > self.stale_after_s

    def key_values(self) -> list[tuple[str, str]]:
        out: list[tuple[str, str]] = []
        for n in self._names:
            age = self.age(n)
            out += [(f"{n} count", str(self._count[n])),
                    (f"{n} rate_hz", format_value(self.rate(n))),
                    (f"{n} age_s", "never" if math.isnan(age) else format_value(age))]
        return out

    def problems(self, clock_stalled_s: float = 0.0) -> list[str]:
        """What is wrong with the inputs. While the node's clock is stalled (sim time without
        /clock: its ages do not grow), staleness is judged on the wall clock."""
        out = []
        wall_now = time.monotonic()
        for n in self._names:
            if self.never_seen(n):
                out.append(f"no messages on {n} yet")
            elif clock_stalled_s > 0.0:
                age = wall_now - self._wall[n]
                if age > self.stale_after_s:
                    out.append(f"{n} stale for {age:.1f} s (wall clock; node clock stalled)")
            elif self.is_stale(n):
                out.append(f"{n} stale for {self.age(n):.1f} s")
        return out


class DiagnosticsTimer:
    """Publishes ``build()``'s statuses on ``/diagnostics`` every ``period_s`` (node clock).

    A second timer on the steady clock watches the node's clock: when it has not advanced for
    more than two periods of wall time (use_sim_time and ``/clock`` stopped, so the first timer
    no longer fires), this one publishes instead, with a "<node>: clock" WARN status added."""

    def __init__(self, node: Any, period_s: float, build: Callable[[], list],
                 topic: str = "/diagnostics", hardware_id: str = "") -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.clock import Clock, ClockType

        self._node = node
        self._build = build
        self.period_s = float(period_s)
        self.hardware_id = hardware_id or node.get_fully_qualified_name()
        self.publisher = node.create_publisher(DiagnosticArray, topic, 10)
        self.timer = node.create_timer(period_s, self.publish_now)
        self._clock_ns = node.get_clock().now().nanoseconds
        self._clock_moved = time.monotonic()   # wall time the node clock was last seen moving
        self._published = time.monotonic()
        self.wall_timer = node.create_timer(period_s, self._watch,
                                            clock=Clock(clock_type=ClockType.STEADY_TIME))

    def _watch(self) -> None:
        now_ns = self._node.get_clock().now().nanoseconds
        if now_ns != self._clock_ns:
            self._clock_ns = now_ns
            self._clock_moved = time.monotonic()
        if time.monotonic() - self._published > 2.0 * self.period_s:
            self.publish_now()

    def clock_stalled_s(self) -> float:
        """How long (wall seconds) the node's clock has not advanced, once that exceeds two
        periods; 0.0 while it runs."""
        stalled = time.monotonic() - self._clock_moved
        return stalled if stalled > 2.0 * self.period_s else 0.0

    def publish_now(self) -> None:
        self._published = time.monotonic()
        stamp = self._node.get_clock().now().to_msg()
        statuses = list(self._build())
        stalled = self.clock_stalled_s()
        if stalled:
            statuses.append(make_status(
                f"{self._node.get_name()}: clock", WARN,
                f"clock stalled for {stalled:.1f} s (use_sim_time and no /clock?): node time "
                "does not advance, input staleness is judged on the wall clock",
                [("node_time_s", self._clock_ns * 1e-9), ("stalled_s", stalled)],
                hardware_id=self.hardware_id))
        self.publisher.publish(make_array(stamp, statuses))
