"""An observer session that records what a running stack publishes (for tests and fault scenarios)."""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field

import numpy as np
import zenoh

from shared.bus import bus_args, open_session, sample_number
from shared.keys import Keys
from shared.messages import JointCommand, RobotState, ServiceStatus


@dataclass
class StateSample:
    """One received RobotState (arrays copied)."""

    t: float  # monotonic arrival [s]
    t_ns: int  # wall-clock arrival [ns]
    seq: int
    t0: int
    q: np.ndarray
    holding: bool
    solver_id: str
    sim_time: float
    number: int | None = None  # the sim publisher's sample number (None: not numbered)


@dataclass
class CommandSample:
    t: float
    seq: int
    solver_id: str
    q: np.ndarray
    qd: np.ndarray
    status: str
    reason: str
    #: the solver's time the command is for [s] (``JointCommand.t_cmd``)
    t_cmd: float = float("nan")


@dataclass
class Observer:
    """A bus session that records what the stack publishes: states, commands, status, liveliness."""

    endpoint: str
    session: str
    keep_commands: bool = True
    states: list[StateSample] = field(default_factory=list)
    commands: list[CommandSample] = field(default_factory=list)
    status: dict[str, ServiceStatus] = field(default_factory=dict)
    status_times: dict[str, list[float]] = field(default_factory=dict)
    alive_events: list[tuple[float, str, str]] = field(default_factory=list)  # (t, "PUT"/"DELETE", "svc/inst")
    first_state_ns: dict[int, int] = field(default_factory=dict)  # seq -> first arrival wall clock [ns]

    def __post_init__(self) -> None:
        self.keys = Keys(self.session)
        self.lock = threading.Lock()
        self.alive: set[str] = set()
        self.z = open_session(bus_args(connect=[self.endpoint], session=self.session))
        self._subs = [
            self.z.declare_subscriber(self.keys.sim_state, self._on_state),
            self.z.declare_subscriber(self.keys.all_status, self._on_status),
            self.z.liveliness().declare_subscriber(self.keys.all_alive, self._on_alive, history=True),
        ]
        if self.keep_commands:
            self._subs.append(self.z.declare_subscriber(self.keys.all_commands, self._on_command))

    def _on_state(self, s: zenoh.Sample) -> None:
        now_ns = time.time_ns()
        m = RobotState.decode(s.payload.to_bytes())
        num = sample_number(s)
        smp = StateSample(
            time.monotonic(), now_ns, m.hdr.seq, m.hdr.t0, m.q, m.holding, m.solver_id, m.sim_time, num and num[1]
        )
        with self.lock:
            self.states.append(smp)
            self.first_state_ns.setdefault(m.hdr.seq, now_ns)

    def _on_command(self, s: zenoh.Sample) -> None:
        m = JointCommand.decode(s.payload.to_bytes())
        with self.lock:
            self.commands.append(
                CommandSample(time.monotonic(), m.hdr.seq, m.solver_id, m.q, m.qd, m.status, m.reason, m.t_cmd)
            )

    def _on_status(self, s: zenoh.Sample) -> None:
        st = ServiceStatus.decode(s.payload.to_bytes())
        name = f"{st.service}/{st.instance}"
        with self.lock:
            self.status[name] = st
            self.status_times.setdefault(name, []).append(time.monotonic())

    def _on_alive(self, s: zenoh.Sample) -> None:
        parsed = Keys.parse_alive(str(s.key_expr))
        if parsed is None:
            return
        name = "/".join(parsed)
        kind = "DELETE" if s.kind == zenoh.SampleKind.DELETE else "PUT"
        with self.lock:
            self.alive_events.append((time.monotonic(), kind, name))
            (self.alive.discard if kind == "DELETE" else self.alive.add)(name)

    def wait_until(self, pred, timeout: float, what: str) -> float:
        """Poll ``pred()`` until true; returns the monotonic time it became true."""
        deadline = time.monotonic() + timeout
        while True:
            with self.lock:
                ok = pred()
            if ok:
                return time.monotonic()
            if time.monotonic() > deadline:
                raise TimeoutError(f"{what}: not within {timeout} s")
            time.sleep(0.01)

    def states_since(self, t: float) -> list[StateSample]:
        with self.lock:
            return [s for s in self.states if s.t >= t]

    def close(self) -> None:
        for s in self._subs:
            try:
                s.undeclare()
            except Exception:  # the session may already be closing
                pass
        self.z.close()
