"""What every retargeter does with a frame before mapping it: count rejects, calibrate on request.

:class:`~services.retarget.retargeter.Retargeter` (the G1's arms) and
:class:`~services.retarget.mobile.MobileRetargeter` (a hand driving a mobile arm) map frames
differently but take them in the same way; this mixin holds that part once. A user class
provides ``config`` (``one_arm_after``), ``calibration``, ``set_calibration(cal)``, ``_guard``
(a :class:`~shared.sequence.SequenceGuard`) and sets ``_recalibrate`` / ``_calib_tries``.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from typing import Any

from services.retarget.calibration import Calibration, CalibrationError
from shared.messages import Header, HumanFrame


class FrameIntake:
    """Reject bookkeeping and auto-calibration shared by the retargeters."""

    config: Any
    calibration: Calibration | None
    rejects: Counter[str]
    last_reject: tuple[str, str] | None
    _recalibrate: bool
    _calib_tries: int

    def set_calibration(self, calibration: Calibration) -> None:  # pragma: no cover - provided by the user class
        raise NotImplementedError

    def _reject(self, reason: str, detail: str) -> None:
        self.rejects[reason] += 1
        self.last_reject = (reason, detail)

    def request_recalibration(self) -> None:
        """Calibrate again from the next frame with valid arm bones."""
        self._recalibrate = True
        self._calib_tries = 0

    def _calibrated(self, frame: HumanFrame, hdr: Header, build: Callable[[HumanFrame], Calibration], hint: str) -> str:
        """Calibrate from ``frame`` when asked to; whether the frame can be mapped.

        Args:
            build: the calibration from one frame (raises CalibrationError when it cannot).
            hint: what the operator must do, appended to the reject.
        Returns:
            "new" (a calibration was installed from this frame: its stream starts here),
            "ok" (calibrated before) or "rejected" (no calibration; ``last_reject`` says why).
        """
        if self._recalibrate:
            try:
                cal = build(frame)
                self._calib_tries += 1
                if "mirrored" in cal.source and self._calib_tries <= self.config.one_arm_after:
                    raise CalibrationError(f"one arm only ({cal.source}); waiting for both arms")
                self.set_calibration(cal)
                self._guard.accept(hdr, frame.source)
                return "new"
            except CalibrationError as exc:
                if self.calibration is None:
                    self._reject("uncalibrated", f"{exc}; {hint}")
                    return "rejected"
        if self.calibration is None:
            self._reject("uncalibrated", f"no calibration and auto-calibration is off; {hint}")
            return "rejected"
        return "ok"
