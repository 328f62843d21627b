"""Retarget service: HumanFrames -> wrist/elbow TaskTargets (seed 000, section 2.2).

Pure logic lives in :mod:`.retargeter` (``Retargeter.step``), :mod:`.mapping`
(eqs. 1-3), :mod:`.orientation` (eq. 4), :mod:`.workspace` (Monte Carlo robot
workspace) and :mod:`.calibration` (operator rest pose and extents). Bus
wiring is in :mod:`.node`, the command lines in :mod:`.cli` and :mod:`.plot_cli`.
"""
