"""Every decoder against adversarial payloads: only MessageError escapes, accepted means valid.

``MIMIC_FUZZ_EXAMPLES`` sets the examples per type (default 500 keeps ``make test``
fast); ``python -m tests.fuzz.run --examples 100000`` is the full run.
"""

from __future__ import annotations

import math
import os

import msgpack
import pytest
from hypothesis import HealthCheck, Phase, given, settings

from shared.messages import MESSAGE_TYPES, SCHEMA_VERSION, HumanFrame, MessageError
from tests.fuzz.fuzz_payloads import (
    adversarial_payload,
    backwards_sequence,
    check_payload,
    valid_message,
)
from tests.fuzz.run import fuzz_type

EXAMPLES = int(os.environ.get("MIMIC_FUZZ_EXAMPLES", "500"))
FUZZ = settings(
    max_examples=EXAMPLES,
    database=None,
    deadline=None,
    phases=[Phase.generate, Phase.shrink],
    suppress_health_check=list(HealthCheck),
)


@pytest.mark.parametrize("type_name", sorted(MESSAGE_TYPES))
def test_decoder_rejects_with_message_error_or_accepts_valid(type_name):
    cls = MESSAGE_TYPES[type_name]

    @FUZZ
    @given(adversarial_payload(type_name))
    def prop(payload):
        outcome = check_payload(cls, payload)  # raises on a crash or an invalid accepted message
        assert outcome == "accepted" or outcome.startswith("rejected:")

    prop()


def test_runner_counts_reasons_and_no_crash():
    r = fuzz_type("HumanFrame", 300, rng_seed=1)
    assert r["examples"] == 300 and r["crashes"] == 0
    assert r["accepted"] + r["rejected"] == 300
    # The operators reach the main rejection paths, not just msgpack garbage.
    for reason in ("msgpack", "type", "nan", "version", "quaternion"):
        assert r["rejected_by_reason"].get(reason, 0) > 0, r["rejected_by_reason"]


@pytest.mark.parametrize(
    ("mutate", "reason"),
    [
        (lambda d: d.__setitem__("v", SCHEMA_VERSION + 1), "version"),
        (lambda d: d["root"][0].__setitem__(1, math.nan), "nan"),
        (lambda d: d["root"][0].__setitem__(2, math.inf), "nan"),
        (lambda d: d["q"].__setitem__(0, [2.0, 0.0, 0.0, 0.0]), "quaternion"),
        (lambda d: d["names"].__setitem__(0, "left_tentacle"), "unknown_name"),
        (lambda d: d.__setitem__("p", [[0.0, 0.0, 0.0]] * 5000), "msgpack"),  # over the unpacker's array limit
        (lambda d: d.__setitem__("hdr", [-1, 0.0, 0]), "range"),
        (lambda d: d.__setitem__("names", "pelvis"), "type"),
    ],
)
def test_named_adversarial_cases(mutate, reason):
    import numpy as np

    d = msgpack.unpackb(valid_message("HumanFrame", np.random.default_rng(0)).encode())
    d["names"], d["p"], d["q"], d["valid"] = ["pelvis", "spine"], [[0.0] * 3] * 2, [[1.0, 0, 0, 0]] * 2, [True] * 2
    mutate(d)
    with pytest.raises(MessageError) as err:
        HumanFrame.decode(msgpack.packb(d))
    assert err.value.reason == reason


def test_truncated_payloads_are_all_rejected():
    import numpy as np

    raw = valid_message("HumanFrame", np.random.default_rng(5)).encode()
    reasons = set()
    for k in range(len(raw)):
        with pytest.raises(MessageError) as err:
            HumanFrame.decode(raw[:k])
        reasons.add(err.value.reason)
    assert reasons <= {"msgpack", "type", "version", "missing", "shape"}


@settings(max_examples=min(EXAMPLES, 100), database=None, deadline=None, suppress_health_check=list(HealthCheck))
@given(backwards_sequence())
def test_time_going_backwards_is_left_to_services(frames):
    """Decoders are stateless: each frame of a backwards sequence decodes with its own seq.

    Ordering is a service-level check (a service must drop stale seqs); the
    running-service fuzz in tests/fuzz/live_fuzz.py feeds these sequences.
    """
    seqs = [HumanFrame.decode(f).hdr.seq for f in frames]
    assert seqs == [msgpack.unpackb(f)["hdr"][0] for f in frames]
    assert seqs != sorted(seqs)
