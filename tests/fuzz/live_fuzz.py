"""Fuzz a running service over the bus and check its ServiceStatus accounting.

:func:`fuzz_live_service` throws payloads at a service's input key. It predicts with the
decoder what the service must do with each one. It then checks the service's
ServiceStatus: every payload the decoder rejects is counted under the same reason, every
accepted one counts as received, and there are no handler errors. It also checks that the
process is still alive and that every message the service published meanwhile decodes
cleanly (no NaN downstream).

    python -m tests.fuzz.live_fuzz --service retarget --examples 100000 --json runs/fuzz_live_retarget.json

To fuzz another service, add it to :data:`SERVICES`. The entry gives its command line,
the input key and type, and the output key and type.
"""

from __future__ import annotations

import argparse
import itertools
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import zenoh

from services.launcher.local_stack import LocalStack
from shared.bus import NumberedPublisher, bus_args, free_port, open_session
from shared.keys import Keys
from shared.messages import HumanFrame, Message, MessageError, ServiceStatus, TaskTargets
from shared.report import emit_json
from tests.fuzz.fuzz_payloads import adversarial_payload, backwards_sequence, for_each_drawn, valid_message


@dataclass(frozen=True)
class ServiceUnderFuzz:
    """How to run one service and where its input and output are."""

    argv: tuple[str, ...]  # after ``mimic``; bus flags are appended
    service: str  # ServiceRunner name (status key)
    input_key: Callable[[Keys], str]
    input_cls: type[Message]
    output_key: Callable[[Keys], str] | None = None
    output_cls: type[Message] | None = None
    instance: str | None = None  # status instance (None for "main")


SERVICES: dict[str, ServiceUnderFuzz] = {
    "retarget": ServiceUnderFuzz(
        ("retarget",), "retarget", lambda k: k.mocap_frame, HumanFrame, lambda k: k.targets, TaskTargets
    ),
    # TODO(lead): add "solve" (TaskTargets -> JointCommand) and "sim" (JointCommand -> RobotState) once merged.
}


def collect_payloads(type_name: str, n: int, rng_seed: int = 0) -> list[bytes]:
    """``n`` adversarial payloads of ``type_name`` drawn with hypothesis."""
    out: list[bytes] = []
    for_each_drawn(adversarial_payload(type_name), n, out.append, rng_seed)
    return out[:n]


def collect_backwards(n_sequences: int, rng_seed: int = 0) -> list[bytes]:
    """Frames of ``n_sequences`` sequences whose seq/stamp go backwards (service-level check)."""
    out: list[bytes] = []
    for_each_drawn(backwards_sequence(), n_sequences, out.extend, rng_seed)
    return out


def expected_outcomes(cls: type[Message], payloads: list[bytes]) -> Counter[str]:
    """What the decoder says about each payload: ``accepted`` or the reject reason."""
    c: Counter[str] = Counter()
    for p in payloads:
        try:
            cls.decode(p)
            c["accepted"] += 1
        except MessageError as exc:
            c[exc.reason] += 1
    return c


class _StatusWatch:
    def __init__(self, session: zenoh.Session, key: str):
        self.latest: ServiceStatus | None = None
        self._cond = threading.Condition()
        self.sub = session.declare_subscriber(key, self._on)

    def _on(self, s: zenoh.Sample) -> None:
        try:
            st = ServiceStatus.decode(s.payload.to_bytes())
        except MessageError:
            return
        with self._cond:
            self.latest = st
            self._cond.notify_all()

    def wait(self, pred: Callable[[ServiceStatus], bool], timeout: float) -> ServiceStatus | None:
        with self._cond:
            self._cond.wait_for(lambda: self.latest is not None and pred(self.latest), timeout)
            return self.latest


def fuzz_live_service(
    endpoint: str,
    session: str,
    target: ServiceUnderFuzz,
    payloads: list[bytes],
    running: Callable[[], bool] | None = None,
    rate: float = 1000.0,
    timeout: float = 30.0,
) -> dict:
    """Publish ``payloads`` to a running service and compare its status with the decoder's verdicts.

    Args:
        endpoint: router the service is connected to. session: its session.
        target: the service description. payloads: bytes to send, in order.
        running: says whether the service process still runs, to check it survived (optional).
        rate: publish rate [Hz]; congestion control BLOCK, so nothing is dropped on the way.

    Returns:
        report dict; ``ok`` is True when every check passed.
    """
    keys = Keys(session)
    expected = expected_outcomes(target.input_cls, payloads)
    n_accepted = expected.pop("accepted", 0)
    out_ok, out_bad = Counter(), Counter()

    def on_output(s: zenoh.Sample) -> None:
        try:
            target.output_cls.decode(s.payload.to_bytes())
            out_ok["n"] += 1
        except MessageError as exc:
            out_bad[exc.reason] += 1

    with open_session(bus_args(connect=[endpoint], session=session)) as z:
        watch = _StatusWatch(z, keys.status(target.service, target.instance))
        first = watch.wait(lambda st: True, timeout)
        if first is None:
            raise RuntimeError(f"no ServiceStatus from {target.service} within {timeout} s")
        if target.output_key is not None:
            z.declare_subscriber(target.output_key(keys), on_output)
        # Numbered like every service's publisher: a sample the service's ring drops (or Zenoh on
        # the way) shows up as a gap in its status, so every payload sent is accounted for.
        pub = NumberedPublisher(z, target.input_key(keys))
        # Its status can come before its subscriber exists: send valid warm-up messages until it
        # counts one, then take the baseline once the counts have settled.
        rng = np.random.default_rng(0)
        deadline = time.monotonic() + timeout
        base_received = first.counts.get("received", 0)
        for i in itertools.count():
            st = watch.wait(lambda st: st.counts.get("received", 0) > base_received, 0.2)
            if st.counts.get("received", 0) > base_received:
                break
            if time.monotonic() > deadline:
                raise RuntimeError(f"{target.service} never counted a valid message within {timeout} s")
            warm = valid_message(target.input_cls.TYPE, rng)
            if hasattr(warm, "hdr"):
                warm.hdr.seq, warm.hdr.stamp = i, i * 1e-3
            pub.put(warm.encode())
        # Baseline once the counts have been still for a while (a fixed sleep let a late warm-up
        # message land after it under load).
        before = _settled(watch, timeout)
        t0 = time.monotonic()
        for i, p in enumerate(payloads):
            wait = t0 + i / rate - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            pub.put(p)
        send_s = time.monotonic() - t0

        after = _settled(watch, timeout)
        time.sleep(0.5)  # the last outputs

    def delta(name: str, which: str = "counts") -> int:
        return getattr(after, which).get(name, 0) - getattr(before, which).get(name, 0)

    delta_rejects = {r: delta(r, "rejects") for r in set(after.rejects) | set(before.rejects) if delta(r, "rejects")}
    decoder_rejects = {r: delta_rejects.get(r, 0) for r in expected}
    service_rejects = {r: v for r, v in delta_rejects.items() if r not in expected}
    received, dropped, errors, gaps = delta("received"), delta("dropped"), delta("errors"), delta("gaps")
    alive = running is None or running()
    missing = sum(expected.values()) - sum(decoder_rejects.values())
    # Two bus styles: decode in the Zenoh callback ("received" = decoded ones) or count every raw
    # sample as received and decode when taken (newest-wins slots, which may evict unread ones).
    # Samples lost before the service saw them (its ring overflowed, or Zenoh dropped) are gaps.
    raw_counting = received + gaps >= len(payloads)
    accounted = (
        received + gaps == len(payloads)
        if raw_counting
        else received + gaps + sum(decoder_rejects.values()) == len(payloads)
    )
    report = {
        "service": target.service,
        "sent": len(payloads),
        "send_s": round(send_s, 2),
        "expected_accepted": n_accepted,
        "received": received,
        "dropped": dropped,
        "gaps": gaps,
        "expected_rejects": dict(sorted(expected.items())),
        "decoder_rejects_counted": dict(sorted(decoder_rejects.items())),
        "service_rejects": dict(sorted(service_rejects.items())),
        "handler_errors": errors,
        "outputs_ok": out_ok["n"],
        "outputs_bad": dict(out_bad),
        "service_alive": alive,
    }
    report["ok"] = bool(
        alive
        and errors == 0
        and not out_bad
        and accounted
        # every counted reason really happened; a reject not counted was evicted unread and counted
        # dropped, or lost on the way and counted as a gap
        and all(decoder_rejects[r] <= expected[r] for r in expected)
        and 0 <= missing <= dropped + gaps
        and (dropped + gaps > 0 or decoder_rejects == dict(expected))
    )
    return report


def _settled(watch: _StatusWatch, timeout: float, quiet: float = 2.0) -> ServiceStatus:
    """Latest status once its counts stopped changing for ``quiet`` seconds (10 status periods of the
    test stacks: a service starved by a loaded machine must not read as finished)."""
    deadline = time.monotonic() + timeout
    last, since = None, time.monotonic()
    while time.monotonic() < deadline:
        st = watch.latest
        sig = (tuple(sorted(st.counts.items())), tuple(sorted(st.rejects.items())))
        if sig != last:
            last, since = sig, time.monotonic()
        elif time.monotonic() - since >= quiet:
            return st
        time.sleep(0.05)
    return watch.latest


def payload_mix(type_name: str, n: int, rng_seed: int = 0) -> list[bytes]:
    """Adversarial payloads interleaved with in-order valid frames (so the service also produces output)
    and backwards-time sequences."""
    rng = np.random.default_rng(rng_seed)
    bad = collect_payloads(type_name, n, rng_seed)
    back = collect_backwards(max(1, n // 200), rng_seed) if type_name == "HumanFrame" else []
    out: list[bytes] = []
    seq = 1 << 41  # above the adversarial seqs, so valid frames keep flowing
    for i, p in enumerate(bad):
        out.append(p)
        if i % 4 == 0:
            msg = valid_message(type_name, rng)
            if hasattr(msg, "hdr"):
                msg.hdr.seq, msg.hdr.stamp = seq, seq * 1e-9
                seq += 1
            out.append(msg.encode())
    return out + back


def run_against(stack: LocalStack, target: ServiceUnderFuzz, payloads: list[bytes], **kw) -> dict:
    """Start the router and ``target`` in ``stack``, fuzz it (:func:`fuzz_live_service`), return the report."""
    stack.start_router()
    stack.start(target.service, argv=["mimic", *target.argv, "--status-period", "0.2"])
    return fuzz_live_service(
        stack.endpoint, stack.session, target, payloads, running=lambda: stack.running(target.service), **kw
    )


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description="fuzz a running service over a loopback router")
    p.add_argument("--service", choices=sorted(SERVICES), default="retarget")
    p.add_argument("--examples", type=int, default=2000, help="adversarial payloads (plus interleaved valid ones)")
    p.add_argument("--rate", type=float, default=1000.0, help="publish rate [Hz]")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", default=None)
    args = p.parse_args(argv)
    target = SERVICES[args.service]
    t0 = time.perf_counter()
    payloads = payload_mix(target.input_cls.TYPE, args.examples, args.seed)
    gen_s = time.perf_counter() - t0
    with LocalStack("livefuzz", f"tcp/127.0.0.1:{free_port()}", status_period=0.2) as stack:
        report = run_against(stack, target, payloads, rate=args.rate, timeout=60.0)
    report["generate_s"] = round(gen_s, 1)
    emit_json(report, args.json, indent=1)
    return 0 if report["ok"] else 1


if __name__ == "__main__":
    sys.exit(main())
