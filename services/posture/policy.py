"""Numpy-only inference of the posture policy: encoder, decoder and gate (seed 004 Fig. 5b).

The model file (``.npz``, written by :func:`save_policy`) holds, per arm side, the encoder
``s -> q̇₀`` and decoder ``(q̇₀, q, x_d) -> operator arm state`` MLPs (tanh on the input and hidden
layers, linear output) with the input/output normalisation already folded into the first and last
layers, plus a JSON ``meta`` entry: state layout, robot, training clips, gate thresholds, sizes,
training report and the sha256 of the weights (checked on load).

At run time both arms go through one batched product per layer (per-arm weights stacked, float32,
biases folded in, buffers preallocated: :meth:`PosturePolicy.act`; ``mimic bench posture`` measures
it, :meth:`PosturePolicy.act_reference` is the plain float64 definition it is tested against).
The gate: the decoder's arm state gives the virtual target ``x_dv`` (:func:`.features.virtual_target`);
the action is used only while ``|x_dv - p| <= threshold`` (per arm), otherwise the caller falls back
to a plain posture task.
"""

from __future__ import annotations

import hashlib
import io
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from services.posture.features import (
    ACTION_DIM,
    ACTION_KINDS,
    ACTION_LIMIT,
    ARM_STATE_DIM,
    DECODER_DIM,
    STATE_DIM,
    ArmFrame,
    decoder_input,
    posture_action,
    virtual_target,
)
from shared.targets import SIDES

FORMAT = "mimic-posture-policy/1"


class PolicyError(ValueError):
    """A model file that cannot be used; the text says why."""


Layers = list[tuple[np.ndarray, np.ndarray]]


def weights_hash(weights: dict[str, np.ndarray]) -> str:
    """sha256 over the weight arrays (sorted by name; dtype, shape and bytes)."""
    h = hashlib.sha256()
    for k in sorted(weights):
        a = np.ascontiguousarray(weights[k], dtype=np.float64)
        h.update(k.encode())
        h.update(str(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()


def save_policy(path: str | Path, weights: dict[str, np.ndarray], meta: dict) -> Path:
    """Write weights (name -> array, names ``<side>.<enc|dec>.<W|b><k>``) and metadata; returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    meta = {**meta, "format": FORMAT, "sha256": weights_hash(weights)}
    buf = io.BytesIO()
    np.savez_compressed(
        buf, meta=np.array(json.dumps(meta)), **{k: np.asarray(v, np.float64) for k, v in weights.items()}
    )
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_bytes(buf.getvalue())
    tmp.replace(path)
    return path


def _layers(weights: dict[str, np.ndarray], prefix: str) -> Layers:
    out, k = [], 0
    while f"{prefix}.W{k}" in weights:
        out.append((weights[f"{prefix}.W{k}"], weights[f"{prefix}.b{k}"]))
        k += 1
    if not out:
        raise PolicyError(f"no layers {prefix}.W0...")
    return out


#: Arithmetic of the real-time path: float32 halves the cost of the products and tanh against float64
#: (``mimic bench posture``) and stays within 1e-6 of the float64 reference on these outputs.
FAST_DTYPE = np.float32


def _with_bias(W: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(in + 1, out): W with b as the last row (the input carries a constant 1 there)."""
    return np.vstack([W, b[None, :]])


def _fast_network(enc: list[Layers], dec: list[Layers]) -> dict:
    """Stacked per-arm weights and preallocated buffers of :meth:`PosturePolicy.act`.

    Encoder layer 0 reads the state ``(Q, p, q)``; decoder layer 0 reads ``(a, q, x_d)`` with
    ``x_d = (Q, p)``: the state part of both goes into one product ``M0`` (2, 15, He + Hd) and only the
    action part ``dec_Wa`` (2, 3, Hd) waits for the encoder.
    """
    dt = FAST_DTYPE

    def stack(mats):
        return np.ascontiguousarray(np.stack(mats), dtype=dt)

    He, Hd = enc[0][0][1].shape[0], dec[0][0][1].shape[0]
    M0 = []
    for e, d in zip(enc, dec):
        (We, be), (Wd, bd) = e[0], d[0]
        dec_state = np.vstack([Wd[ACTION_DIM + 7 :], Wd[ACTION_DIM : ACTION_DIM + 7]])  # rows (x_d, q) = S order
        M0.append(np.hstack([_with_bias(We, be), _with_bias(dec_state, bd)]))
    f = {"He": He, "M0": stack(M0), "dec_Wa": stack([d[0][0][:ACTION_DIM] for d in dec])}
    f["enc_W"] = [stack([_with_bias(*e[k]) for e in enc]) for k in range(1, len(enc[0]))]
    # a = h W + b and the decoder's layer-0 term a Wa = h (W Wa) + b Wa: one product gives both.
    # Columns padded to a multiple of 8 (zeros): measured 20 % faster than the odd 3 + Hd.
    pad = -(ACTION_DIM + Hd) % 8
    f["enc_Wc"] = stack([np.hstack([_with_bias(*e[-1]), _with_bias(*e[-1]) @ d[0][0][:ACTION_DIM],
                                    np.zeros((e[-1][0].shape[0] + 1, pad))]) for e, d in zip(enc, dec)])  # fmt: skip
    f["C"] = np.empty((2, 1, ACTION_DIM + Hd + pad), dt)
    f["dec_W"] = [stack([_with_bias(*d[k]) for d in dec]) for k in range(1, len(dec[0]))]
    f["u"] = np.ones((2, 1, STATE_DIM + 1), dt)
    f["P0"] = np.empty((2, 1, He + Hd), dt)
    # Hidden activations with a trailing constant 1 (the next layer's bias row).
    f["enc_h"] = [np.ones((2, 1, W.shape[1] + 1), dt) for W in [e0[0] for e0 in enc[0]][:-1]]
    f["dec_h"] = [np.ones((2, 1, W.shape[1] + 1), dt) for W in [d0[0] for d0 in dec[0]][:-1]]
    f["enc_P"] = [np.empty((2, 1, W.shape[2]), dt) for W in f["enc_W"][:-1]]
    f["dec_P"] = [np.empty((2, 1, W.shape[2]), dt) for W in f["dec_W"][:-1]]
    f["a"] = np.empty((2, 1, ACTION_DIM), dt)
    f["dec_T"] = np.empty((2, 1, Hd), dt)
    f["z"] = np.empty((2, 1, ARM_STATE_DIM), dt)
    # Views used every tick, made once.
    f["u_S"] = f["u"][:, 0, :STATE_DIM]
    f["P0_enc"], f["P0_dec"] = f["P0"][:, :, :He], f["P0"][:, :, He:]
    f["enc_h0"], f["dec_h0"] = f["enc_h"][0][:, :, :-1], f["dec_h"][0][:, :, :-1]
    for net in ("enc", "dec"):  # (weights, pre-activation buffer, next activation) of each hidden layer
        hid = zip(f[f"{net}_W"][:-1], f[f"{net}_P"], f[f"{net}_h"][1:])
        f[f"{net}_hidden"] = [(W, P, h[:, :, :-1]) for W, P, h in hid]
    f["C_a"], f["C_dec"] = f["C"][:, 0, :ACTION_DIM], f["C"][:, :, ACTION_DIM : ACTION_DIM + Hd]
    f["a64"] = np.empty((2, ACTION_DIM))
    f["qd0"] = np.zeros((2, ACTION_DIM))
    f["x_dv"] = np.empty((2, 3))
    f["gap"] = np.empty(2)
    f["gate"] = np.empty(2, bool)
    return f


def mlp(layers: Layers, x: np.ndarray) -> np.ndarray:
    """tanh MLP: tanh after every layer but the last (x (..., in) -> (..., out))."""
    for W, b in layers[:-1]:
        x = np.tanh(x @ W + b)
    W, b = layers[-1]
    return x @ W + b


@dataclass
class PolicyOutput:
    """One inference for both arms (rows in :data:`.features.SIDES` order).

    Attributes:
        qd0: (2, 3) null-space velocities [rad/s], within ±ACTION_LIMIT. x_dv: (2, 3) virtual targets [m].
        gap: (2,) |x_dv - p| [m]. gate: (2,) True where the action may be used.
        action: (2, 3) the encoder's output: q̇₀ itself, or the shoulder posture q* [rad] (posture kind).
    """

    qd0: np.ndarray
    x_dv: np.ndarray
    gap: np.ndarray
    gate: np.ndarray
    action: np.ndarray


class PosturePolicy:
    """The learned posture policy of one robot (both arms).

    Args:
        weights: per-arm layer arrays (see :func:`save_policy`). meta: the file's metadata.
    """

    def __init__(self, weights: dict[str, np.ndarray], meta: dict):
        self.meta = meta
        try:
            enc = [_layers(weights, f"{s}.enc") for s in SIDES]
            dec = [_layers(weights, f"{s}.dec") for s in SIDES]
            self.arms = [ArmFrame(np.asarray(meta["arms"][s]["centre"], float), float(meta["arms"][s]["upper"]),
                                  float(meta["arms"][s]["fore"])) for s in SIDES]  # fmt: skip
            self.threshold = np.array([float(meta["gate_threshold"][s]) for s in SIDES])
            self.Q_ref = np.array([meta["q_ref"][s] for s in SIDES], dtype=float)
            self.kind = str(meta.get("action_kind", "velocity"))  # files before the posture kind: velocity
            self.gain = float(meta.get("posture_gain", 0.0))
        except (KeyError, TypeError, ValueError) as exc:
            raise PolicyError(f"model metadata incomplete: {exc}") from None
        if self.kind not in ACTION_KINDS or (self.kind == "posture" and not self.gain > 0.0):
            raise PolicyError(f"action kind {self.kind!r} (gain {self.gain}): expected one of {ACTION_KINDS}, gain > 0")
        for side, e, d in zip(SIDES, enc, dec):
            if e[0][0].shape[0] != STATE_DIM or e[-1][0].shape[1] != ACTION_DIM:
                raise PolicyError(f"{side} encoder maps {e[0][0].shape[0]} -> {e[-1][0].shape[1]}, expected 14 -> 3")
            if d[0][0].shape[0] != DECODER_DIM or d[-1][0].shape[1] != ARM_STATE_DIM:
                raise PolicyError(f"{side} decoder maps {d[0][0].shape[0]} -> {d[-1][0].shape[1]}, expected 17 -> 6")
        self._enc64, self._dec64 = enc, dec
        self._centre = np.array([a.centre for a in self.arms])
        self._len = np.array([[a.upper, a.fore] for a in self.arms])
        #: the encoder's output layer folds into the decoder's first (the decoder reads the raw action)
        self._fold = self.kind != "velocity"
        self._fast = _fast_network(enc, dec)
        self._geo = self._centre.tolist()  # the gate's constants as floats (plain arithmetic per tick)
        self._geo_len = self._len.tolist()
        self._thr = self.threshold.tolist()

    @property
    def robot(self) -> str:
        return str(self.meta.get("robot", ""))

    @classmethod
    def load(cls, path: str | Path) -> PosturePolicy:
        """Read and check a model file (format, hash, shapes).

        Raises:
            PolicyError: unreadable, wrong format, or weights that do not match their hash.
        """
        try:
            with np.load(Path(path), allow_pickle=False) as z:
                arrays = {k: z[k] for k in z.files}
        except (OSError, ValueError) as exc:
            raise PolicyError(f"cannot read posture policy {path}: {exc}") from None
        if "meta" not in arrays:
            raise PolicyError(f"{path}: no metadata (not a posture policy file)")
        try:
            meta = json.loads(str(arrays.pop("meta")))
        except json.JSONDecodeError as exc:
            raise PolicyError(f"{path}: metadata is not JSON: {exc}") from None
        if meta.get("format") != FORMAT:
            raise PolicyError(f"{path}: format {meta.get('format')!r}, expected {FORMAT!r}")
        if weights_hash(arrays) != meta.get("sha256"):
            raise PolicyError(f"{path}: weights do not match their sha256 (file altered or truncated)")
        return cls(arrays, meta)

    def act(self, S: np.ndarray) -> PolicyOutput:
        """Actions, virtual targets and gate for states S (2, 14) (left, right): the real-time path.

        The numbers of :meth:`act_reference` (float32 products: within 1e-6 of it) in a dozen numpy
        calls: both arms at once (per-arm weights stacked, one batched product per layer), biases as a
        constant-1 input, the encoder's first layer and the decoder's ``(x_d, q)`` part in one product,
        the encoder's linear output layer folded into the decoder's first layer (when the decoder reads
        the raw output), preallocated buffers, and the gate's and action's dozen scalars in plain float
        arithmetic. The returned arrays are those buffers: valid until the next call.
        """
        f = self._fast
        mm, th = np.matmul, np.tanh
        f["u_S"][:] = S  # u (2, 1, 15) = (Q, p, q, 1)
        mm(f["u"], f["M0"], out=f["P0"])  # (2, 1, He + Hd): encoder layer 0 | decoder's (x_d, q, 1) part
        h = f["enc_h"]
        th(f["P0_enc"], out=f["enc_h0"])
        for k, (W, P, out) in enumerate(f["enc_hidden"]):
            th(mm(h[k], W, out=P), out=out)
        T = f["dec_T"]
        if self._fold:
            mm(h[-1], f["enc_Wc"], out=f["C"])  # (2, 1, 3 + Hd): action | its decoder layer-0 part
            a32 = f["C_a"]
            np.add(f["C_dec"], f["P0_dec"], out=T)
        else:  # velocity kind: the decoder reads the bounded action
            a32 = mm(h[-1], f["enc_W"][-1], out=f["a"])
            np.minimum(np.maximum(a32, -ACTION_LIMIT, out=a32), ACTION_LIMIT, out=a32)
            np.add(mm(a32, f["dec_Wa"], out=T), f["P0_dec"], out=T)
            a32 = a32[:, 0]
        g = f["dec_h"]
        th(T, out=f["dec_h0"])
        for k, (W, P, out) in enumerate(f["dec_hidden"]):
            th(mm(g[k], W, out=P), out=out)
        z = mm(g[-1], f["dec_W"][-1], out=f["z"]).tolist()  # per arm: upper-arm, forearm directions
        act = a32.tolist()
        s = S.tolist()
        x_dv, gap, gate = f["x_dv"], f["gap"], f["gate"]
        qd = [[0.0] * ACTION_DIM, [0.0] * ACTION_DIM]  # elbow kind: zero (the caller tracks the target)
        for i in (0, 1):
            si = s[i]
            if self.kind == "posture":  # K (q* - q), bounded; the shoulder joints are state entries 7..9
                qd[i] = [min(max(self.gain * (x - q), -ACTION_LIMIT), ACTION_LIMIT) for x, q in zip(act[i], si[7:10])]
            elif self.kind == "velocity":
                qd[i] = act[i]
            # Gate: x_dv = c + L_u u/|u| + L_f f/|f|, gap = |x_dv - p|; a non-finite state entry closes its
            # arm's gate (NaN compares False; the sum also catches inf).
            ux, uy, uz, fx, fy, fz = z[i][0]
            (cx, cy, cz), (Lu, Lf), (px, py, pz) = self._geo[i], self._geo_len[i], si[4:7]
            ku = Lu / max(math.sqrt(ux * ux + uy * uy + uz * uz), 1e-9)
            kf = Lf / max(math.sqrt(fx * fx + fy * fy + fz * fz), 1e-9)
            x, y, w = cx + ku * ux + kf * fx, cy + ku * uy + kf * fy, cz + ku * uz + kf * fz
            d = math.sqrt((x - px) ** 2 + (y - py) ** 2 + (w - pz) ** 2)
            x_dv[i] = (x, y, w)
            gap[i] = d
            gate[i] = d <= self._thr[i] and math.isfinite(sum(si))
        a, qd0 = f["a64"], f["qd0"]
        a[:] = act
        qd0[:] = qd
        return PolicyOutput(qd0, x_dv, gap, gate, a)

    def act_reference(self, S: np.ndarray) -> PolicyOutput:
        """:meth:`act` written plainly, per arm in float64 (the definition the fast path is tested against)."""
        A, QD, XDV, GAP, GATE = [], [], [], [], []
        for i in range(2):
            s = np.asarray(S[i], dtype=float)
            a = mlp(self._enc64[i], s)
            if self.kind == "posture":
                qd0 = posture_action(a, s[7 : 7 + ACTION_DIM], self.gain)
            elif self.kind == "velocity":
                a = qd0 = np.clip(a, -ACTION_LIMIT, ACTION_LIMIT)
            else:
                qd0 = np.zeros(ACTION_DIM)
            z = mlp(self._dec64[i], decoder_input(a, s))
            x_dv = virtual_target(self.arms[i], z)
            gap = float(np.linalg.norm(x_dv - s[4:7]))
            A.append(a)
            QD.append(qd0)
            XDV.append(x_dv)
            GAP.append(gap)
            GATE.append(bool(gap <= self.threshold[i]) and bool(np.isfinite(s).all()))
        return PolicyOutput(np.array(QD), np.array(XDV), np.array(GAP), np.array(GATE), np.array(A))

    def virtual_target(self, side: int, z: np.ndarray) -> np.ndarray:
        """x_dv (…, 3) of arm states (…, 6) of arm ``side`` (0 left, 1 right)."""
        return virtual_target(self.arms[side], z)
