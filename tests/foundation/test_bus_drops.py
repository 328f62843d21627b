"""Every lost message is counted: mailbox drops (newest-wins, bounded queue) and samples lost on the way (gaps)."""

from __future__ import annotations

import logging
import threading
import time

import msgpack
import pytest
import zenoh

from shared.bus import (
    LatestSlot,
    NumberedPublisher,
    ServiceRunner,
    StatusCounters,
    bus_args,
    sample_number,
    zenoh_config,
)
from shared.messages import MessageError
from shared.sequence import GapCounter

# ----------------------------------------------------------------------------- pure logic


def test_gap_counter_counts_skipped_numbers_per_publisher():
    g = GapCounter()
    assert [g.see(1, n) for n in (1, 2, 5, 6)] == [0, 0, 2, 0]
    # Another publisher interleaved on the same stream has its own count.
    assert [g.see(2, n) for n in (10, 13)] == [0, 2]
    assert g.see(1, 7) == 0
    assert g.total == 4


def test_gap_counter_restart_and_duplicate_are_no_gap_and_count_afresh():
    g = GapCounter()
    g.see(1, 50)
    assert g.see(1, 50) == 0  # duplicate
    assert g.see(1, 3) == 0  # restarted with the same id
    assert g.see(1, 5) == 1  # counted from the restart, not from 50
    assert g.total == 1


def test_gap_counter_forgets_the_least_recent_publisher_beyond_its_table():
    g = GapCounter(max_sources=2)
    g.see(1, 1)
    g.see(2, 1)
    g.see(3, 1)  # evicts publisher 1
    assert g.see(1, 9) == 0  # seen as new, not as 7 lost
    assert g.see(3, 4) == 2


def _status() -> StatusCounters:
    return StatusCounters("t", "main", logging.getLogger("test"))


def test_newest_wins_slot_keeps_the_last_and_counts_the_overwritten():
    st = _status()
    slot = LatestSlot(st, "cmd")
    for i in range(5):
        slot.put(i)
    assert slot.take() == 4
    assert slot.take() is None
    assert st.count("dropped.cmd") == 4


def test_bounded_queue_keeps_order_and_drops_the_oldest_counted():
    st = _status()
    slot = LatestSlot(st, "frames", depth=3)
    for i in range(5):
        slot.put(i)
    assert [slot.take(), slot.take(), slot.take(), slot.take()] == [2, 3, 4, None]
    assert st.count("dropped.frames") == 2


def test_queue_skips_stale_messages_but_never_the_newest():
    st = _status()
    slot = LatestSlot(st, "frames", depth=32, max_age=0.05)
    for i in range(3):
        slot.put(i)
    assert slot.take() == 0  # fresh: taken in order
    time.sleep(0.08)
    slot.put(3)
    # 1 and 2 waited past max_age while 3 arrived: skipped and counted; 3 is taken.
    assert [slot.take(), slot.take()] == [3, None]
    assert st.count("dropped.frames") == 2
    slot.put(4)
    time.sleep(0.08)
    assert slot.take() == 4  # stale but the newest: kept
    assert st.count("dropped.frames") == 2


def test_slot_decodes_on_take_once_and_counts_bad_payloads():
    st = _status()
    calls = []

    def decode(raw: bytes) -> int:
        calls.append(raw)
        if raw == b"bad":
            raise MessageError("msgpack", "not a number")
        return int(raw)

    slot = LatestSlot(st, "s", decode=decode, depth=2)
    for raw in (b"1", b"bad", b"3"):
        slot.put(raw)
    # b"1" was overwritten before anyone took it: never decoded.
    assert slot.take() is None and st.snapshot().rejects == {"msgpack": 1}
    assert slot.take() == 3
    assert calls == [b"bad", b"3"]
    assert st.count("dropped.s") == 1


# ----------------------------------------------------------------------------- on a real bus


def _wait(pred, timeout: float = 20.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if pred():
            return True
        time.sleep(0.02)
    return pred()


@pytest.mark.integration
def test_a_publisher_that_skips_numbers_shows_as_gaps_in_the_service_status(router):
    args = bus_args(connect=[router], session="gaps")
    client = zenoh.open(zenoh_config(args))
    try:
        with ServiceRunner("listener", args, install_signals=False) as svc:
            slot = svc.subscribe_latest(svc.keys.mocap_frame, msgpack.unpackb, "frames", depth=100)
            pub = NumberedPublisher(client, svc.keys.mocap_frame)
            # Until the subscription has propagated, samples may be lost before anyone counts them.
            assert _wait(lambda: (pub.put(msgpack.packb(0)), svc.status.count("received.frames") > 0)[1])
            while slot.take() is not None:
                pass
            base_received = svc.status.count("received.frames")
            assert svc.status.count("gaps") == 0
            for skip in (0, 3, 0, 0, 2, 0):
                pub.number += skip  # the numbers a lossy transport would never deliver
                pub.put(msgpack.packb(pub.number + 1))
            assert _wait(lambda: svc.status.count("received.frames") >= base_received + 6)
            assert svc.status.count("gaps.frames") == 5
            assert svc.status.snapshot().counts["gaps"] == 5
            assert svc.status.count("dropped") == 0
    finally:
        client.close()


@pytest.mark.integration
def test_numbered_samples_carry_source_and_number_and_plain_ones_do_not(router):
    args = bus_args(connect=[router], session="num")
    a = zenoh.open(zenoh_config(args))
    b = zenoh.open(zenoh_config(args))
    got: list = []
    try:
        sub = b.declare_subscriber("num/x", lambda s: got.append((s.payload.to_bytes(), sample_number(s))))
        pub = NumberedPublisher(a, "num/x")
        plain = a.declare_publisher("num/x")
        assert _wait(lambda: (pub.put(b"x"), len(got) > 0)[1])
        pub.put(b"y")
        plain.put(b"z")
        assert _wait(lambda: len(got) >= 2 and got[-1][0] == b"z")
        numbers = dict(got)
        assert numbers[b"y"] == (pub.source, pub.number)
        assert numbers[b"z"] is None
        # The rest of the Zenoh publisher stays reachable (ingest waits on matching_status).
        assert pub.matching_status.matching
        sub.undeclare()
    finally:
        a.close()
        b.close()


@pytest.mark.integration
def test_ring_reader_polls_newest_wins_and_waits_in_order_without_a_receiver_thread(router):
    args = bus_args(connect=[router], session="reader")
    client = zenoh.open(zenoh_config(args))
    try:
        with ServiceRunner("listener", args, install_signals=False) as svc:
            threads = threading.active_count()
            latest = svc.subscribe_reader(svc.keys.sim_state, msgpack.unpackb, "state")
            queue = svc.subscribe_reader(svc.keys.mocap_frame, msgpack.unpackb, "frames", depth=4)
            assert threading.active_count() == threads  # the consumer reads the rings itself
            state_pub = NumberedPublisher(client, svc.keys.sim_state)
            frame_pub = NumberedPublisher(client, svc.keys.mocap_frame)
            assert _wait(lambda: (state_pub.put(msgpack.packb(-1)), latest.take() is not None)[1])
            time.sleep(0.3)
            while latest.take() is not None:  # warm-up samples still on the way
                pass
            t = time.monotonic()
            assert latest.take() is None and time.monotonic() - t < 0.05  # nothing waiting: no blocking
            base = svc.status.count("dropped.state")
            for i in range(5):
                state_pub.put(msgpack.packb(i))
            time.sleep(1.0)  # the five wait in the ring; nothing has read them yet
            # Each poll gives the newest arrival, the ones before it counted as dropped (not lost). On a
            # loaded machine the last samples can still be on the way after the sleep: poll until the
            # fifth, then every sample was either taken or counted, and none came after a newer one.
            seen: list[int] = []
            assert _wait(lambda: (seen.append(latest.take()), seen[-1] == 4)[1])
            seen = [v for v in seen if v is not None]
            assert seen == sorted(seen) and seen[0] > 0, seen  # the first poll already skipped sample 0
            assert svc.status.count("dropped.state") - base == 5 - len(seen)
            assert svc.status.count("gaps.state") == 0
            assert latest.take() is None
            # The queue: everything in order, wait_take() blocking until each comes.
            assert _wait(lambda: (frame_pub.put(msgpack.packb(-1)), queue.take() is not None)[1])
            time.sleep(0.3)
            while queue.take() is not None:
                pass
            got = []
            waiter = threading.Thread(target=lambda: got.extend(queue.wait_take() for _ in range(3)))
            waiter.start()
            for i in range(3):
                time.sleep(0.05)
                frame_pub.put(msgpack.packb(i))
            waiter.join(10)
            assert got == [0, 1, 2]
            # Closing the session ends a waiting consumer.
            ended = threading.Thread(target=queue.wait_take)
            ended.start()
        ended.join(10)
        assert not ended.is_alive() and queue.closed
    finally:
        client.close()
