"""Reader of mmWave Studio / DCA1000 CLI raw captures (`*_Raw_<n>.bin`).

These files hold only the concatenated packet payloads (headers stripped, lost packets already
zero-filled by the recorder), so frame k is bytes [k*F, (k+1)*F). A capture that is not a whole
number of frames is refused, except for a zero tail shorter than one packet (the FPGA pads its
last packet), so a wrong cfg can never silently shift every later frame.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from mmatch.errors import ParseError

from .layout import FrameGeometry, disabled_lane_energy
from .protocol import MAX_PAYLOAD_BYTES

log = logging.getLogger(__name__)


class RawCapture:
    """Memory-mapped raw capture of frames of `geom.frame_bytes` bytes.

    paths: one file or a list of split files (`_Raw_0.bin`, `_Raw_1.bin`, ...), read in order
    as one stream. expected_frames: the cfg's frameCfg numFrames (0/None = unknown); a capture
    with more frames than that does not match the cfg and is refused.
    """

    def __init__(self, paths, geom: FrameGeometry, expected_frames: int | None = None) -> None:
        if isinstance(paths, (str, Path)):
            paths = [paths]
        self.paths = [Path(p) for p in paths]
        self.geom = geom
        F = geom.frame_bytes
        chunks = []
        for p in self.paths:
            try:
                size = p.stat().st_size
            except OSError as exc:
                raise ParseError(f"{p}: cannot read: {exc}") from exc
            chunks.append(np.memmap(p, dtype=np.uint8, mode="r") if size else np.zeros(0, np.uint8))
        data = chunks[0] if len(chunks) == 1 else np.concatenate(chunks)
        name = ", ".join(str(p) for p in self.paths)
        extra = len(data) % F
        self.padding_bytes = 0
        if extra:
            tail = data[len(data) - extra :]
            if len(data) >= F and extra < MAX_PAYLOAD_BYTES and not tail.any():
                self.padding_bytes = extra
                log.info(
                    "%s: ignoring %d zero bytes of packet padding after the last frame", name, extra
                )
            else:
                raise ParseError(
                    f"{name}: {len(data)} bytes is not a whole number of {F}-byte frames "
                    f"({len(data) // F} frames + {extra} bytes); the cfg does not match the "
                    f"capture (chirps x lanes x samples x 4 = {geom.num_chirps} x {geom.lanes}"
                    f" x {geom.num_samples} x 4)"
                )
        self.num_frames = len(data) // F
        if self.num_frames == 0:
            raise ParseError(f"{name}: no complete frame ({len(data)} bytes < {F})")
        if expected_frames and self.num_frames > expected_frames:
            raise ParseError(
                f"{name}: {self.num_frames} frames but the cfg's frameCfg records only "
                f"{expected_frames}; the cfg does not match the capture"
            )
        self._data = data[: self.num_frames * F]
        if geom.num_rx < 4 and geom.lanes == 4:
            leak = disabled_lane_energy(self.frame(0), geom)
            if leak:
                raise ParseError(
                    f"{name}: disabled RX lanes carry data (|sample| up to {leak}); "
                    "the cfg's channelCfg RX mask does not match the capture"
                )

    def __len__(self) -> int:
        return self.num_frames

    def frame(self, k: int) -> np.ndarray:
        """uint8 (frame_bytes,) raw bytes of frame k."""
        if not 0 <= k < self.num_frames:
            raise IndexError(f"frame {k} out of 0..{self.num_frames - 1}")
        F = self.geom.frame_bytes
        return self._data[k * F : (k + 1) * F]

    def __iter__(self) -> Iterator[np.ndarray]:
        for k in range(self.num_frames):
            yield self.frame(k)
