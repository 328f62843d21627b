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
    ELBOW_KINDS,
    STATE_DIM,
    ArmFrame,
    action_dim,
    decoder_dim,
    decoder_input,
    posture_action,
    virtual_target,
)
from services.posture.swivel import SwivelFrame
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


def _fast_network(enc: list[Layers], dec: list[Layers], fold: bool, A: int = ACTION_DIM) -> dict:
    """Stacked per-arm weights and preallocated buffers of :meth:`PosturePolicy.act`.

    The state lives at the tail of the buffer ``X`` (2, 1, H + 15) = ``[h | 1 | S]``, whose head ``h`` is
    the encoder's last hidden layer: the encoder's layer 0 reads the tail ``[1 | S]``, and (``fold``) one
    product of the whole buffer gives the encoder's output ``a`` and the decoder's layer-0
    pre-activation ``a Wa + (x_d, q) W + b`` together (the encoder's linear output layer folded into the
    decoder's first layer, the decoder's state rows and bias beside it). Without ``fold`` (velocity kind:
    the decoder reads the clipped action) the action goes into ``Y = [a | 1 | S]`` first. A: the action's
    length.
    """
    dt = FAST_DTYPE
    SD = STATE_DIM

    def stack(mats):
        return np.ascontiguousarray(np.stack(mats), dtype=dt)

    def dec_state(Wd):  # decoder rows of (x_d, q) in state order S = (Q, p, q) = (x_d, q)
        return np.vstack([Wd[A + 7 :], Wd[A : A + 7]])

    He = [W.shape[1] for W, _ in enc[0][:-1]]  # encoder hidden widths
    Hd = [W.shape[1] for W, _ in dec[0][:-1]]  # decoder hidden widths
    HL = He[-1]
    f = {"X": np.ones((2, 1, HL + 1 + SD), dt)}
    f["X_S"] = f["X"][:, 0, HL + 1 :]
    f["u"] = f["X"][:, :, HL:]  # [1 | S]
    f["M0"] = stack([np.vstack([e[0][1][None, :], e[0][0]]) for e in enc])  # (2, 15, He0): bias row first
    # Encoder hidden buffers with a trailing constant 1 (the next layer's bias row); the last is X's head.
    hbuf = [np.ones((2, 1, h + 1), dt) for h in He[:-1]] + [f["X"][:, :, : HL + 1]]
    f["enc_P"] = [np.empty((2, 1, h), dt) for h in He]
    f["enc_out"] = [b[:, :, :-1] for b in hbuf]
    f["enc_in"] = hbuf[:-1]  # inputs of encoder layers 1..: the previous hidden buffer
    f["enc_W"] = [stack([_with_bias(*e[k]) for e in enc]) for k in range(1, len(He))]
    pad = -(A + Hd[0]) % 8  # columns padded to a multiple of 8 (zeros): measured ~20 % faster than odd widths
    if fold:
        # [h | 1 | S] @ [[W_out, W_out Wa, 0], [b_out, b_out Wa + b_d, 0], [0, W_state, 0]]
        Wc = []
        for e, d in zip(enc, dec):
            (Wo, bo), (Wd, bd) = e[-1], d[0]
            Wa = Wd[:A]
            top = np.hstack([Wo, Wo @ Wa, np.zeros((HL, pad))])
            one = np.hstack([bo, bo @ Wa + bd, np.zeros(pad)])[None, :]
            low = np.hstack([np.zeros((SD, A)), dec_state(Wd), np.zeros((SD, pad))])
            Wc.append(np.vstack([top, one, low]))
        f["Wc"] = stack(Wc)
        f["C"] = np.empty((2, 1, A + Hd[0] + pad), dt)
        f["C_a"], f["C_dec"] = f["C"][:, 0, :A], f["C"][:, :, A : A + Hd[0]]
    else:
        f["W_out"] = stack([_with_bias(*e[-1]) for e in enc])  # (2, HL + 1, 3)
        f["X_h"] = f["X"][:, :, : HL + 1]
        f["Y"] = np.ones((2, 1, A + 1 + SD), dt)
        f["Y_a"], f["Y_S"] = f["Y"][:, :, :A], f["Y"][:, 0, A + 1 :]
        f["Wy"] = stack([np.vstack([d[0][0][:A], d[0][1][None, :], dec_state(d[0][0])]) for d in dec])
        f["T"] = np.empty((2, 1, Hd[0]), dt)
    gbuf = [np.ones((2, 1, h + 1), dt) for h in Hd]
    f["dec_h0"], f["dec_last"] = gbuf[0][:, :, :-1], gbuf[-1]
    f["dec_hidden"] = [(gbuf[k], stack([_with_bias(*d[k + 1]) for d in dec]), np.empty((2, 1, Hd[k + 1]), dt),
                        gbuf[k + 1][:, :, :-1]) for k in range(len(Hd) - 1)]  # fmt: skip
    f["enc_hidden"] = list(zip(f["enc_in"], f["enc_W"], f["enc_P"][1:], f["enc_out"][1:]))
    f["enc_P"] = f["enc_P"][0]
    f["W_z"] = stack([_with_bias(*d[-1]) for d in dec])
    f["z"] = np.empty((2, 1, ARM_STATE_DIM), dt)
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
        action: (2, A) the encoder's output: q̇₀ itself, the shoulder posture q* [rad] (posture kind), the
            elbow [m] (elbow kind) or its swivel angle (cos φ, sin φ) (swivel kind, unnormalised); float32
            from :meth:`PosturePolicy.act`.
        elbow: (2, 3) [m] the elbow target of the kinds in ``ELBOW_KINDS``: ``action`` itself (elbow kind)
            or the elbow placed at the angle on the circle that reaches the wrist ``p`` (swivel kind).
    """

    qd0: np.ndarray
    x_dv: np.ndarray
    gap: np.ndarray
    gate: np.ndarray
    action: np.ndarray
    elbow: np.ndarray


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
        A, DD = action_dim(self.kind), decoder_dim(self.kind)
        for side, e, d in zip(SIDES, enc, dec):
            if e[0][0].shape[0] != STATE_DIM or e[-1][0].shape[1] != A:
                raise PolicyError(f"{side} encoder maps {e[0][0].shape[0]} -> {e[-1][0].shape[1]}, expected 14 -> {A}")
            if d[0][0].shape[0] != DD or d[-1][0].shape[1] != ARM_STATE_DIM:
                raise PolicyError(f"{side} decoder maps {d[0][0].shape[0]} -> {d[-1][0].shape[1]}, expected {DD} -> 6")
        #: swivel kind: each arm's circle and angle reference (recorded in the file: ``arms.<side>.swivel``)
        self.swivel: list[SwivelFrame] = []
        if self.kind == "swivel":
            try:
                self.swivel = [SwivelFrame.from_dict(meta["arms"][s]["swivel"]) for s in SIDES]
            except (KeyError, TypeError, ValueError) as exc:
                raise PolicyError(f"swivel policy without its angle frames: {exc}") from None
        self._enc64, self._dec64 = enc, dec
        self._centre = np.array([a.centre for a in self.arms])
        self._len = np.array([[a.upper, a.fore] for a in self.arms])
        #: the encoder's output layer folds into the decoder's first (the decoder reads the raw action)
        self._fold = self.kind != "velocity"
        self._fast = _fast_network(enc, dec, self._fold, A)
        self._posture, self._velocity = self.kind == "posture", self.kind == "velocity"
        #: the output is an elbow target (``PolicyOutput.elbow``) for the arm's elbow task
        self.gives_elbow = self.kind in ELBOW_KINDS
        # the gate's constants as floats (plain arithmetic per tick): centre (3), L_u, L_f, threshold
        self._gate_const = [(*c, *ln, t) for c, ln, t in zip(self._centre.tolist(), self._len.tolist(),
                                                              self.threshold.tolist())]  # fmt: skip
        f = self._fast
        action = f["C_a"] if self._fold else f["Y_a"][:, 0]
        elbow = action if self.kind == "elbow" else np.zeros((2, 3))
        self._out = PolicyOutput(f.pop("qd0"), f.pop("x_dv"), f.pop("gap"), f.pop("gate"), action, elbow)

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

        The numbers of :meth:`act_reference` (float32 products: within 1e-6 of it) in about ten numpy
        calls: both arms at once (per-arm weights stacked, one batched product per layer), biases as a
        constant-1 input, the state at the tail of the encoder's last hidden buffer so that one product
        gives the action and the decoder's layer-0 pre-activation (the encoder's linear output layer
        folded into the decoder's first layer, when the decoder reads the raw output), preallocated
        buffers, and the gate's dozen scalars in plain float arithmetic. The returned object and its
        arrays are the policy's buffers: valid until the next call.
        """
        f = self._fast
        mm, th = np.matmul, np.tanh
        f["X_S"][:] = S  # X (2, 1, H + 15) = [h | 1 | S]
        th(mm(f["u"], f["M0"], out=f["enc_P"]), out=f["enc_out"][0])  # encoder layer 0 reads [1 | S]
        for h, W, P, out in f["enc_hidden"]:
            th(mm(h, W, out=P), out=out)
        if self._fold:
            mm(f["X"], f["Wc"], out=f["C"])  # (2, 1, 3 + Hd): action | decoder layer-0 pre-activation
            th(f["C_dec"], out=f["dec_h0"])
        else:  # velocity kind: the decoder reads the bounded action
            Ya = f["Y_a"]
            mm(f["X_h"], f["W_out"], out=Ya)
            np.clip(Ya, -ACTION_LIMIT, ACTION_LIMIT, out=Ya)
            f["Y_S"][:] = S
            th(mm(f["Y"], f["Wy"], out=f["T"]), out=f["dec_h0"])
        for g, W, P, out in f["dec_hidden"]:
            th(mm(g, W, out=P), out=out)
        z = mm(f["dec_last"], f["W_z"], out=f["z"]).tolist()  # per arm: upper-arm, forearm directions
        s = S.tolist()
        out = self._out
        if self._posture:  # K (q* - q), bounded; the shoulder joints are state entries 7..9
            act, K, L = out.action.tolist(), self.gain, ACTION_LIMIT
            out.qd0[:] = [[min(max(K * (x - q), -L), L) for x, q in zip(act[i], s[i][7:10])] for i in (0, 1)]
        elif self._velocity:
            np.copyto(out.qd0, out.action)
        # elbow kinds: qd0 stays zero (the caller tracks the target)
        if self.swivel:
            act = out.action.tolist()
            out.elbow[:] = [w.place_floats(a[0], a[1], *si[4:7]) for w, a, si in zip(self.swivel, act, s)]
        # Gate: x_dv = c + L_u u/|u| + L_f f/|f|, gap = |x_dv - p|; a non-finite state entry closes its
        # arm's gate (NaN compares False; the sum also catches inf).
        xs, ds, gs = [], [], []
        for (zi,), si, (cx, cy, cz, Lu, Lf, thr) in zip(z, s, self._gate_const):
            ux, uy, uz, fx, fy, fz = zi
            ku = Lu / max(math.sqrt(ux * ux + uy * uy + uz * uz), 1e-9)
            kf = Lf / max(math.sqrt(fx * fx + fy * fy + fz * fz), 1e-9)
            x, y, w = cx + ku * ux + kf * fx, cy + ku * uy + kf * fy, cz + ku * uz + kf * fz
            d = math.hypot(x - si[4], y - si[5], w - si[6])
            xs.append((x, y, w))
            ds.append(d)
            gs.append(d <= thr and math.isfinite(sum(si)))
        out.x_dv[:] = xs
        out.gap[:] = ds
        out.gate[:] = gs
        return out

    def act_reference(self, S: np.ndarray) -> PolicyOutput:
        """:meth:`act` written plainly, per arm in float64 (the definition the fast path is tested against)."""
        A, QD, XDV, GAP, GATE, E = [], [], [], [], [], []
        for i in range(2):
            s = np.asarray(S[i], dtype=float)
            a = mlp(self._enc64[i], s)
            if self.kind == "posture":
                qd0 = posture_action(a, s[7 : 7 + ACTION_DIM], self.gain)
            elif self.kind == "velocity":
                a = qd0 = np.clip(a, -ACTION_LIMIT, ACTION_LIMIT)
            else:
                qd0 = np.zeros(ACTION_DIM)
            E.append(self.swivel[i].place(a, s[4:7]) if self.swivel else a if self.kind == "elbow" else np.zeros(3))
            z = mlp(self._dec64[i], decoder_input(a, s))
            x_dv = virtual_target(self.arms[i], z)
            gap = float(np.linalg.norm(x_dv - s[4:7]))
            A.append(a)
            QD.append(qd0)
            XDV.append(x_dv)
            GAP.append(gap)
            GATE.append(bool(gap <= self.threshold[i]) and bool(np.isfinite(s).all()))
        return PolicyOutput(np.array(QD), np.array(XDV), np.array(GAP), np.array(GATE), np.array(A), np.array(E))

    def virtual_target(self, side: int, z: np.ndarray) -> np.ndarray:
        """x_dv (…, 3) of arm states (…, 6) of arm ``side`` (0 left, 1 right)."""
        return virtual_target(self.arms[side], z)
