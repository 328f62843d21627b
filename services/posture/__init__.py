"""Learned human-like arm posture from wrist-only input (seed 004 section 3).

- :mod:`.features`: the state/action layout ``s = (Q, p, q)``, ``a = q̇₀`` and the operator arm state.
- :mod:`.policy`: numpy-only inference (encoder, decoder, gate) for the real-time path.
- :mod:`.rollout`: closed-loop CLIK (eq. 2) on real clips, driven by the expert or the policy.
- :mod:`.train` (PyTorch, optional extra ``train``): behaviour cloning (eq. 7) and Algorithm 1.
- :mod:`.cli`: ``mimic posture train`` and ``mimic posture bench``.
"""
