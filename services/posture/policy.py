"""Numpy-only inference of the posture policy: encoder, decoder and gate (seed 004 Fig. 5b).

The model file (``.npz``, written by :func:`save_policy`) holds, per arm side, the encoder
``s -> q̇₀`` and decoder ``(q̇₀, q, x_d) -> operator arm state`` MLPs (tanh on the input and hidden
layers, linear output) with the input/output normalisation already folded into the first and last
layers, plus a JSON ``meta`` entry: state layout, robot, training clips, gate thresholds, sizes,
training report and the sha256 of the weights (checked on load).

At run time both arms go through one block-diagonal network, so a tick costs one matrix product
per layer for both arms (``mimic posture bench`` measures it). The gate: the decoder's arm state
gives the virtual target ``x_dv`` (:func:`.features.virtual_target`); the action is used only while
``|x_dv - p| <= threshold`` (per arm), otherwise the caller falls back to a plain posture task.
"""

from __future__ import annotations

import hashlib
import io
import json
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


def _block(layers: list[Layers]) -> Layers:
    """One block-diagonal network from equally shaped per-arm networks."""
    fused = []
    for parts in zip(*layers):
        rows = sum(W.shape[0] for W, _ in parts)
        cols = sum(W.shape[1] for W, _ in parts)
        W = np.zeros((rows, cols))
        r = c = 0
        for Wi, _ in parts:
            W[r : r + Wi.shape[0], c : c + Wi.shape[1]] = Wi
            r += Wi.shape[0]
            c += Wi.shape[1]
        fused.append((W, np.concatenate([b for _, b in parts])))
    return fused


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
        self.enc = _block(enc)
        self.dec = _block(dec)
        self._centre = np.array([a.centre for a in self.arms])
        self._len = np.array([[a.upper, a.fore] for a in self.arms])
        self._dec_in = np.zeros((2, DECODER_DIM))

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
        """Actions, virtual targets and gate for states S (2, 14) (left, right)."""
        x = S.reshape(-1)
        for W, b in self.enc[:-1]:
            x = np.tanh(x @ W + b)
        W, b = self.enc[-1]
        a = (x @ W + b).reshape(2, ACTION_DIM)
        if self.kind == "posture":
            # The shoulder joints lead the arm chain (features.action_joints): state entries 7..9.
            qd0 = posture_action(a, S[:, 7 : 7 + ACTION_DIM], self.gain)
        else:
            a = qd0 = np.clip(a, -ACTION_LIMIT, ACTION_LIMIT)
        d = self._dec_in  # (2, 17): (q̇₀, q, x_d), reused
        d[:, :ACTION_DIM] = a
        d[:, ACTION_DIM : ACTION_DIM + 7] = S[:, 7:14]
        d[:, ACTION_DIM + 7 :] = S[:, 0:7]
        x = d.reshape(-1)
        for W, b in self.dec[:-1]:
            x = np.tanh(x @ W + b)
        W, b = self.dec[-1]
        z = (x @ W + b).reshape(2, 2, 3)  # per arm: upper-arm and forearm directions
        n = np.sqrt(np.einsum("ijk,ijk->ij", z, z))
        x_dv = self._centre + np.einsum("ijk,ij->ik", z, self._len / np.maximum(n, 1e-9))
        e = x_dv - S[:, 4:7]
        gap = np.sqrt(np.einsum("ij,ij->i", e, e))
        gate = (gap <= self.threshold) & np.isfinite(a).all(1)
        gate &= np.isfinite(qd0).all(1)
        return PolicyOutput(qd0, x_dv, gap, gate, a)

    def virtual_target(self, side: int, z: np.ndarray) -> np.ndarray:
        """x_dv (…, 3) of arm states (…, 6) of arm ``side`` (0 left, 1 right)."""
        return virtual_target(self.arms[side], z)
