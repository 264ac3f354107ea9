"""The ROS graph as a user runs it: the installed executables as separate processes.

* fast replay, bag_player -> filter_node -> recorder_node, three processes, ten times in a row:
  every message the filter published (its ``published`` diagnostic) is in the bag;
* the recorder stopped (SIGSTOP, 0.5 s) in the middle of a fast replay loses nothing: the fdi/* writers
  and the recorder keep every unacknowledged sample (KEEP_ALL); before, a KEEP_LAST writer history
  of 100 lost the samples a reader was more than 100 behind (~0.04 s of fast replay);
* timed replay at 10x real time with the filter's default parameters: no input lost;
* the player ending its replay while the filter is stopped waits for it (drain_timeout) and
  the filter receives every input.

The last four tests take their recorder and filter from ``prestarted``, which starts them while
the test before runs, in the other of two private ROS domains: their start-up and discovery
(~4-5 s) was a quarter of each test's time.
"""
from __future__ import annotations

import os
import signal
import subprocess
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import harness  # noqa: F401  (private ROS domain, inherited by the subprocesses)
import pytest

REPO = Path(__file__).resolve().parents[2]
EXE_DIR = REPO / "install" / "flight_fdi" / "lib" / "flight_fdi"
SECONDS = 40.0           # the test flight: 2000 INS + 400 reference messages, 800 filter steps


@pytest.fixture(scope="module")
def bag40(tmp_path_factory):
    from flight_fdi.sim import SimConfig, simulate_to_bag

    path = tmp_path_factory.mktemp("graph") / "flight"
    simulate_to_bag(SimConfig(duration_s=SECONDS, seed=12), str(path))
    return path


def start(exe: str, cwd: Path, *ros_args: str, domain: int | None = None) -> subprocess.Popen:
    """An installed node executable, started through install/setup.bash as a user does; in ROS
    domain ``domain`` (default: the test's)."""
    path = EXE_DIR / exe
    assert path.exists(), "run make setup first (install/ is missing)"
    cmd = ["bash", "-c", 'source "$0" >/dev/null && exec "$@"',
           str(REPO / "install" / "setup.bash"), str(path), "--ros-args", *ros_args]
    env = None if domain is None else {**os.environ, "ROS_DOMAIN_ID": str(domain)}
    return subprocess.Popen(cmd, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, env=env)


def stop(procs: list[subprocess.Popen]) -> list[str]:
    for p in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGINT)
    out = []
    for p in procs:
        try:
            out.append(p.communicate(timeout=30)[0])
        except subprocess.TimeoutExpired:
            p.send_signal(signal.SIGUSR1)       # the node's threads' stacks (runner.py), then
            try:                                # kill: the log says where it hung
                p.communicate(timeout=5)
            except subprocess.TimeoutExpired:
                pass
            p.kill()
            out.append(p.communicate()[0])
    return out


class DiagnosticsProbe:
    """The latest key-values of every /diagnostics status, by status name."""

    def __init__(self, ros, name: str = ""):
        from diagnostic_msgs.msg import DiagnosticArray

        self.ros = ros
        self.values: dict[str, dict[str, str]] = {}
        self.levels: dict[str, int] = {}
        self.messages: dict[str, str] = {}
        self.hardware: dict[str, str] = {}
        node = ros.node(name or f"probe_{os.getpid()}")
        node.create_subscription(DiagnosticArray, "/diagnostics", self._on, 100)

    def _on(self, msg) -> None:
        for st in msg.status:
            self.values[st.name] = {kv.key: kv.value for kv in st.values}
            self.levels[st.name] = st.level[0] if isinstance(st.level, bytes) else st.level
            self.messages[st.name] = st.message
            self.hardware[st.name] = st.hardware_id

    def get(self, status: str, key: str, default: str = "") -> str:
        return self.values.get(status, {}).get(key, default)


def bag_counts(bag: Path) -> dict[str, int]:
    from flight_fdi.bagio.reader import read_messages

    counts: dict[str, int] = {}
    for topic, *_ in read_messages(bag, topics=["/fdi/state", "/fdi/innovation"]):
        counts[topic] = counts.get(topic, 0) + 1
    return counts


def wait_inputs(ros, probe, f: str, ins: int, reference: int, timeout: float = 20) -> None:
    """Spin until filter ``f``'s diagnostics count every input; a timeout says what it had."""
    try:
        ros.spin_until(lambda: probe.get(f"{f}: inputs", "received_ins") == str(ins)
                       and probe.get(f"{f}: inputs", "received_reference") == str(reference),
                       timeout=timeout, what=f"{ins} INS and {reference} reference inputs")
    except harness.SpinTimeout as exc:
        raise harness.SpinTimeout(f"{exc}; the filter's inputs: "
                                  f"{probe.values.get(f'{f}: inputs')}") from None


def start_consumers(tmp_path: Path, run: int, domain: int | None = None) -> list:
    """recorder_<run> (recording to tmp_path/rec<run>) and filter_<run>, in ROS domain
    ``domain``."""
    return [start("recorder_node", tmp_path, "-r", f"__node:=recorder_{run}",
                  "-p", f"output:={tmp_path / f'rec{run}'}", domain=domain),
            start("filter_node", tmp_path, "-r", f"__node:=filter_{run}",
                  "-p", "diagnostics_period_s:=0.25", domain=domain)]


def start_filter(tmp_path: Path, f: str, domain: int | None = None) -> subprocess.Popen:
    """filter_node ``f`` with its default parameters (diagnostics every 0.25 s), in ROS domain
    ``domain``."""
    return start("filter_node", tmp_path, "-r", f"__node:={f}", "-p", "diagnostics_period_s:=0.25",
                 domain=domain)


#: the processes the last four tests consume, by test, in the order the tests run
CONSUMERS = ("stalled /fdi/state", "stalled /recorder_99/recorded", "10x", "drain")


class Prestarted:
    """The processes each of the last four tests consumes (CONSUMERS: a recorder and a filter, or
    a filter), started while the test before it runs -- in the other of two private ROS domains
    (the tests' own and the second), so that they hear nothing of it -- and handed over by
    :meth:`take` with a harness and probe of their domain, made before the processes started
    (a harness made later took 1-2 s to discover them)."""

    def __init__(self, tmp_path_factory) -> None:
        self.tmp = tmp_path_factory
        self.ready: dict[str, tuple] = {}    # started, not taken: (procs, domain, folder)
        self.taken: list[subprocess.Popen] = []
        self.done: set[str] = set()
        self.graphs: dict[int | None, tuple] = {}   # domain -> (harness, probe)

    def _start(self, key: str, domain: int | None) -> None:
        if domain not in self.graphs:
            h = harness.RosHarness(domain_id=domain)
            self.graphs[domain] = (h, DiagnosticsProbe(h, f"probe_{os.getpid()}_{domain}"))
        folder = self.tmp.mktemp("graph")
        procs = (start_consumers(folder, 99, domain) if key.startswith("stalled")
                 else [start_filter(folder, f"filter_{key}", domain)])
        self.ready[key] = (procs, domain, folder)

    def take(self, key: str) -> tuple:
        """(processes, ROS domain (None: the tests' own), their working folder, a harness in the
        domain, its DiagnosticsProbe) of ``key``; starts the next test's in the other domain."""
        stop([p for p in self.taken if p.poll() is None])   # (a failed test's, if any)
        if key not in self.ready:
            busy = {d for _, d, _ in self.ready.values()}
            self._start(key, harness.SECOND_DOMAIN_ID if None in busy else None)
        procs, domain, folder = self.ready.pop(key)
        self.done.add(key)
        self.taken += procs
        other = harness.SECOND_DOMAIN_ID if domain is None else None
        later = [k for k in CONSUMERS[CONSUMERS.index(key) + 1:]
                 if k not in self.done and k not in self.ready]
        if later and other not in {d for _, d, _ in self.ready.values()}:
            self._start(later[0], other)
        return (procs, domain, folder, *self.graphs[domain])

    def close(self) -> None:
        """Stops what no test stopped (a failed test's, or those of a test not run)."""
        try:
            stop([p for p in self.taken if p.poll() is None]
                 + [p for procs, _, _ in self.ready.values() for p in procs])
        finally:
            for h, _ in self.graphs.values():
                h.close()


@pytest.fixture(scope="module")
def prestarted(tmp_path_factory):
    pre = Prestarted(tmp_path_factory)
    try:
        yield pre
    finally:
        pre.close()


def one_replay(ros, probe, bag, tmp_path, run: int, stall_s: float = 0.0,
               ack_topic: str = "/fdi/state", domain: int | None = None, consumers=None,
               while_playing=None, stopper: ThreadPoolExecutor | None = None):
    """One fast replay through three processes -- the recorder and the filter (started here
    unless ``consumers`` were, by ``start_consumers``), then the player -- in ROS domain
    ``domain`` (``ros`` and ``probe`` in it too); ``while_playing()`` is called once the player
    has started. Returns the counts to compare (``finish_replay``); with ``stopper``, a future
    of them: the processes are stopped on that thread, while the caller goes on."""
    f, r = f"filter_{run}", f"recorder_{run}"
    procs = consumers or start_consumers(tmp_path, run, domain)
    try:
        # the recorder has matched the filter once it recorded the filter's latched models
        ros.spin_until(lambda: probe.get(f"{r}: recording", "/fdi/model count") == "2",
                       timeout=60, what="the recorder recording the filter's models")
        player = start("bag_player", tmp_path, "-p", f"bag:={bag}", "-p", "fast:=true",
                       "-p", f"ack_topic:={ack_topic}", "-p", "publish_clock:=false",
                       domain=domain)
        procs.append(player)
        if while_playing is not None:
            while_playing()
        if stall_s:
            ros.spin_until(lambda: int(probe.get(f"{f}: inputs", "published", "0")) > 0,
                           timeout=60, what="the replay starting")
            os.kill(procs[0].pid, signal.SIGSTOP)
            time.sleep(stall_s)  # the stall itself (not a synchronisation)
            os.kill(procs[0].pid, signal.SIGCONT)
        ros.spin_until(lambda: player.poll() is not None, timeout=120, what="the replay")
        assert player.returncode == 0, player.communicate()[0]
        expected = 2 * int(SECONDS * 10) - 2   # channels x steps (the last reference has no INS
        #                                        sample after it)
        ros.spin_until(lambda: int(probe.get(f"{f}: inputs", "published", "0")) >= expected,
                       timeout=30, what="the filter publishing every step")
        published = int(probe.get(f"{f}: inputs", "published"))
        # the samples after the last step arrive after its diagnostics: wait for them too
        wait_inputs(ros, probe, f, ins=2000, reference=400)
        ros.spin_until(lambda: probe.get(f"{r}: recording", "/fdi/state count") ==
                       probe.get(f"{r}: recording", "/fdi/innovation count") == str(published),
                       timeout=20, what="the recorder catching up")
    except BaseException:
        stop(procs)
        raise
    v = probe.values[f"{f}: inputs"]
    counts = dict(published=published, received_ins=int(v["received_ins"]),
                  received_reference=int(v["received_reference"]),
                  dropped=sum(int(x) for k, x in v.items() if k.startswith("dropped_")))
    if stopper is None:
        return finish_replay(procs, tmp_path / f"rec{run}", counts)
    return stopper.submit(finish_replay, procs, tmp_path / f"rec{run}", counts)


def finish_replay(procs: list, out: Path, counts: dict) -> dict:
    """Stops a replay's processes -- the recorder and the filter must exit 0 -- and adds what
    the recorder's bag ``out`` holds to ``counts``."""
    logs = stop(procs)
    if [p.returncode for p in procs[:2]] != [0, 0]:
        print("\n".join(logs))                 # whole (the assertion message is shortened)
    assert [p.returncode for p in procs[:2]] == [0, 0], logs
    return dict(counts, bag=bag_counts(out))


@pytest.mark.slow
def test_fast_replay_across_processes_records_every_message_ten_times(ros, bag40, tmp_path):
    """Ten replays, one after the other, each through three new processes. The recorder and the
    filter of the next replay start while one plays -- in the other of two private ROS domains,
    so that they hear nothing of it -- and are ready when it ends (their start-up and discovery,
    ~5 s, were half of a replay's time); a replay's processes are stopped (and its bag read)
    while the next one starts."""
    other = harness.RosHarness(domain_id=harness.SECOND_DOMAIN_ID)
    graphs = [(ros, DiagnosticsProbe(ros), None),
              (other, DiagnosticsProbe(other), harness.SECOND_DOMAIN_ID)]
    ready = [start_consumers(tmp_path, 0)]

    def start_next(run: int) -> None:
        if run < 10:
            ready.append(start_consumers(tmp_path, run, graphs[run % 2][2]))

    replays = []
    try:
        with ThreadPoolExecutor(max_workers=1) as stopper:   # (waits for every stop)
            for run in range(10):
                h, probe, domain = graphs[run % 2]
                replays.append(one_replay(h, probe, bag40, tmp_path, run, domain=domain,
                                          consumers=ready.pop(), stopper=stopper,
                                          while_playing=lambda: start_next(run + 1)))
    finally:
        for procs in ready:                    # the next replay's, after a failure
            stop(procs)
        other.close()
    missing = []
    for replay in replays:
        c = replay.result()
        assert c["received_ins"] == 2000 and c["received_reference"] == 400
        assert c["dropped"] == 0
        missing.append((c["published"] - c["bag"].get("/fdi/state", 0),
                        c["published"] - c["bag"].get("/fdi/innovation", 0)))
    print(f"states / innovations missing from the bag in 10 runs: {missing}")
    assert missing == [(0, 0)] * 10


@pytest.mark.slow
@pytest.mark.parametrize("ack_topic", ["/fdi/state", "/recorder_99/recorded"])
def test_a_stalled_recorder_loses_nothing(bag40, prestarted, ack_topic):
    """SIGSTOP on the recorder for 0.5 s in the middle of a fast replay (a loaded machine
    descheduling it, exaggerated; with the old KEEP_LAST 100 writers 0.2 s lost states): nothing
    is lost, whichever acknowledgement paces the player. (Stops of 1 s and more are beyond Fast
    DDS's shared-memory port health check, 1 s by default: see docs/design.md.)"""
    procs, domain, folder, h, probe = prestarted.take(f"stalled {ack_topic}")
    c = one_replay(h, probe, bag40, folder, 99, stall_s=0.5, ack_topic=ack_topic, domain=domain,
                   consumers=procs)
    assert c["dropped"] == 0 and c["received_ins"] == 2000
    assert c["bag"] == {"/fdi/state": c["published"], "/fdi/innovation": c["published"]}


def stalled_timed_replay(ros, probe, tmp_path, f: str, seconds: float, seed: int,
                         rate: float, stall_s: float, procs: list | None = None,
                         domain: int | None = None) -> tuple[list, bool]:
    """filter_node ``f`` (default parameters; started here unless ``procs`` holds it, from
    ``start_filter``) and bag_player at ``rate`` on a simulated flight of ``seconds``, two
    processes in ROS domain ``domain``; the filter stopped (SIGSTOP) for ``stall_s`` once the
    replay started (a loaded machine descheduling it, exaggerated). Returns the processes once
    the player exited 0 (the caller stops them), and whether the player was still running when
    the stall ended."""
    from flight_fdi.sim import SimConfig, simulate_to_bag

    procs = procs or [start_filter(tmp_path, f, domain)]
    try:
        bag = tmp_path / f"flight_{f}"
        simulate_to_bag(SimConfig(duration_s=seconds, seed=seed), str(bag))
        ros.spin_until(lambda: f"{f}: inputs" in probe.values, timeout=60,
                       what="the filter starting")
        player = start("bag_player", tmp_path, "-p", f"bag:={bag}", "-p", f"rate:={rate}",
                       domain=domain)
        procs.append(player)
        ros.spin_until(lambda: int(probe.get(f"{f}: inputs", "received_ins", "0")) > 0,
                       timeout=60, what="the replay starting")
        os.kill(procs[0].pid, signal.SIGSTOP)
        time.sleep(stall_s)  # the stall itself (not a synchronisation)
        running = player.poll() is None
        os.kill(procs[0].pid, signal.SIGCONT)
        ros.spin_until(lambda: player.poll() is not None, timeout=60, what="the replay")
        assert player.returncode == 0, player.communicate()[0]
    except BaseException:
        stop(procs)
        raise
    return procs, running


@pytest.mark.slow
def test_10x_real_time_across_processes_with_default_parameters_loses_no_input(prestarted):
    """bag_player at rate 10 (600 messages/s) -> filter_node with its default parameters, two
    processes; the filter is stopped for 0.5 s in the middle (a loaded machine descheduling it,
    exaggerated): every input is received and fused, nothing dropped. The old defaults
    (best effort, depth 100) lost ~150 INS samples in the same run (bench/bench_replay_10x.py)."""
    f = "filter_10x"
    procs, domain, folder, h, probe = prestarted.take("10x")
    procs, _ = stalled_timed_replay(h, probe, folder, f, 30.0, 13, 10.0, 0.5, procs, domain)
    try:
        wait_inputs(h, probe, f, ins=1500, reference=300)
        h.spin_until(lambda: probe.get(f"{f}: inputs", "published") in ("598", "600"),
                     timeout=10, what="every step published")
    finally:
        stop(procs)
    v = probe.values[f"{f}: inputs"]
    assert {k: x for k, x in v.items() if k.startswith("dropped_") and x != "0"} == {}
    assert probe.get(f"{f}: channel x", "fused") == probe.get(f"{f}: channel y", "fused")
    assert int(probe.get(f"{f}: channel x", "fused")) * 2 == int(v["published"])
    # the diagnostics name what they are about
    assert probe.hardware[f"{f}: inputs"] == "/ins/velocity"
    assert probe.hardware[f"{f}: channel y"] == "/ins/velocity y"
    assert "y.velocity_error" in probe.values[f"{f}: channel y"]
    assert probe.hardware["bag_player: replay"]


@pytest.mark.slow
def test_player_exiting_while_the_consumer_is_stalled_loses_nothing(prestarted):
    """The player ends its replay while the filter is stopped (SIGSTOP, 2.5 s): with its default
    drain_timeout it waits until the filter acknowledged everything, then exits; the filter
    receives every input. Measured without the drain (drain_timeout 0, the old behaviour): the
    player exited during the stall and the filter received 18 of the 150 INS samples -- the
    rest died with the writer (a CI run lost the last 3 INS samples of a fast replay so)."""
    f = "filter_drain"
    procs, domain, folder, h, probe = prestarted.take("drain")
    # the 3-s flight at rate 2 ends 1.5 s after its start, inside the stall
    procs, still_draining = stalled_timed_replay(h, probe, folder, f, 3.0, 14, 2.0, 2.5, procs,
                                                 domain)
    try:
        wait_inputs(h, probe, f, ins=150, reference=30)
    finally:
        logs = stop(procs)
    assert still_draining, logs[1]
    assert "NOT acknowledged" not in logs[1]
