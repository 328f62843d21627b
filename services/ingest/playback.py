"""Clip playback schedule (pure): which frame is due when, with what header.

Deadlines are computed from the start time, never accumulated, so sleeping
late on one frame does not delay the next ones (no drift). Across loops the
clip time keeps increasing: loop ``k`` adds ``k * (duration + 1 / fps)``.
"""

from __future__ import annotations

from dataclasses import dataclass

from services.ingest.clip import Clip
from shared.messages import HumanFrame


@dataclass
class Playback:
    """Iterate a clip at ``rate`` times real time.

    Attributes:
        clip: the clip (already sliced to the wanted interval).
        rate: playback speed factor (> 0).
        loop: start again after the last frame.
        first_seq: seq of the first frame published.
    """

    clip: Clip
    rate: float = 1.0
    loop: bool = False
    first_seq: int = 0
    _k: int = 0  # frames emitted

    def __post_init__(self) -> None:
        if not self.rate > 0:
            raise ValueError(f"rate must be > 0, got {self.rate}")
        if self.clip.n_frames == 0:
            raise ValueError("empty clip")
        self.period = self.clip.duration + 1.0 / self.clip.fps  # clip time of one loop [s]

    @property
    def done(self) -> bool:
        return not self.loop and self._k >= self.clip.n_frames

    def _index(self) -> tuple[int, int]:
        return divmod(self._k, self.clip.n_frames)

    def stamp(self) -> float:
        """Clip time of the next frame [s], monotonic across loops."""
        lap, i = self._index()
        return float(self.clip.times[i]) + lap * self.period

    def deadline(self, start: float) -> float:
        """Monotonic time at which the next frame is due [s], for playback started at ``start``."""
        return start + self.stamp() / self.rate

    def step(self, t0_ns: int) -> HumanFrame:
        """The next frame (seq increases by 1 per call), then advance.

        Raises:
            StopIteration: when done (no loop).
        """
        if self.done:
            raise StopIteration
        _lap, i = self._index()
        frame = self.clip.frame(i, self.first_seq + self._k, t0_ns)
        frame.hdr.stamp = self.stamp()
        self._k += 1
        return frame
