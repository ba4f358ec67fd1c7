"""Raw ADC layouts of the LVDS stream -> complex cube (ti_formats.md section 1b).

* 4 lanes, interleaved (AR1243/AWR2243, xWR12xx/14xx): per sample index, 8 int16 =
  I(RX0) I(RX1) I(RX2) I(RX3) Q(RX0) Q(RX1) Q(RX2) Q(RX3); samples in order, chirps in order.
  The four lanes are always present; a disabled RX lane carries zeros.
* 2 lanes, non-interleaved (xWR16xx/18xx/68xx): per chirp, RX0's N samples then RX1's ...
  (enabled RX only); within each, groups of 4 int16 = I(n) I(n+1) Q(n) Q(n+1).

Chirps come in frame order: loop 0's chirps in `tx_order`, loop 1's, ... The TDM-MIMO cube is
(loops, virtual channels, samples) with virtual channel v = slot * num_rx + rx, where slot is the
chirp's position in the loop (TI's order: the first chirp's TX with RX0..RX3, then the next
chirp's TX). With the usual AWR2243 chirp order TX0, TX1, TX2 that is TX0's RX0-RX3, TX1's, TX2's.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

import numpy as np

from mmatch.errors import ConfigError, ParseError


class RawLayout(str, Enum):
    FOUR_LANE = "4lane"
    TWO_LANE = "2lane"


@dataclass(frozen=True)
class FrameGeometry:
    """What one raw frame holds.

    layout: LVDS layout; num_loops: chirp loops (Doppler bins); tx_order: TX index per chirp
    slot of a loop; rx: enabled RX indices (ascending); num_samples: ADC samples per chirp;
    iq_swap: Q before I in each pair (adcbufCfg SampleSwap).
    """

    layout: RawLayout
    num_loops: int
    tx_order: tuple[int, ...]
    rx: tuple[int, ...]
    num_samples: int
    iq_swap: bool = False

    def __post_init__(self) -> None:
        if self.num_loops < 1 or self.num_samples < 1 or not self.tx_order or not self.rx:
            raise ConfigError(f"empty frame geometry: {self}")
        if self.layout is RawLayout.TWO_LANE and self.num_samples % 2:
            raise ConfigError("the 2-lane layout needs an even number of ADC samples")
        if any(not 0 <= r <= 3 for r in self.rx) or list(self.rx) != sorted(set(self.rx)):
            raise ConfigError(f"RX indices {self.rx} must be distinct, ascending, 0..3")

    @classmethod
    def from_chirp(
        cls, chirp, layout: RawLayout | str = RawLayout.FOUR_LANE, iq_swap: bool = False
    ) -> "FrameGeometry":
        """From drivers.ti.cfg.ChirpParams (TDM-MIMO: each chirp of a loop uses another TX)."""
        order = tuple(chirp.tx_order)
        if len(set(order)) != len(order):
            raise ConfigError(
                f"chirp TX order {order} repeats a TX within a loop; "
                "only TDM-MIMO (one TX per chirp slot) is supported"
            )
        rx = tuple(i for i in range(4) if chirp.rx_mask >> i & 1)
        return cls(RawLayout(layout), chirp.num_loops, order, rx, chirp.num_adc_samples, iq_swap)

    @property
    def num_chirps(self) -> int:
        """Chirps per frame (all TX)."""
        return self.num_loops * len(self.tx_order)

    @property
    def num_rx(self) -> int:
        return len(self.rx)

    @property
    def num_virtual(self) -> int:
        return len(self.tx_order) * len(self.rx)

    @property
    def lanes(self) -> int:
        """RX channels present in the stream: always 4 for the 4-lane layout."""
        return 4 if self.layout is RawLayout.FOUR_LANE else len(self.rx)

    @property
    def frame_bytes(self) -> int:
        """Raw bytes per frame: chirps x lanes x samples x 4 (complex int16)."""
        return self.num_chirps * self.lanes * self.num_samples * 4


def _as_int16(raw, geom: FrameGeometry) -> np.ndarray:
    a = (
        np.frombuffer(raw, dtype="<i2")
        if not isinstance(raw, np.ndarray)
        else raw.view("<i2").reshape(-1)
    )
    if a.size * 2 != geom.frame_bytes:
        raise ParseError(f"raw frame of {a.size * 2} bytes, the cfg implies {geom.frame_bytes}")
    return a


def raw_to_cube(raw, geom: FrameGeometry) -> np.ndarray:
    """One raw frame (bytes or uint8/int16 array) -> complex64 (loops, virtual, samples)."""
    a = _as_int16(raw, geom)
    C, N = geom.num_chirps, geom.num_samples
    out = np.empty((C, geom.num_rx, N), dtype=np.complex64)
    o = out.view(np.float32).reshape(C, geom.num_rx, N, 2)
    i_pos, q_pos = (1, 0) if geom.iq_swap else (0, 1)
    if geom.layout is RawLayout.FOUR_LANE:
        s = a.reshape(C, N, 2, 4)  # chirp, sample, I/Q, lane
        rx = list(geom.rx)
        if rx == [0, 1, 2, 3]:
            o[..., 0] = s[:, :, i_pos, :].transpose(0, 2, 1)
            o[..., 1] = s[:, :, q_pos, :].transpose(0, 2, 1)
        else:
            o[..., 0] = s[:, :, i_pos, rx].transpose(0, 2, 1)
            o[..., 1] = s[:, :, q_pos, rx].transpose(0, 2, 1)
    else:
        s = a.reshape(C, geom.num_rx, N // 2, 2, 2)  # chirp, rx, sample pair, I/Q, even/odd
        o5 = out.view(np.float32).reshape(C, geom.num_rx, N // 2, 2, 2)  # ..., even/odd, re/im
        o5[..., 0] = s[:, :, :, i_pos, :]
        o5[..., 1] = s[:, :, :, q_pos, :]
    return out.reshape(geom.num_loops, geom.num_virtual, N)


def disabled_lane_energy(raw, geom: FrameGeometry) -> int:
    """Largest |sample| on the 4-lane stream's disabled RX lanes (0 if the cfg matches the data)."""
    if geom.layout is not RawLayout.FOUR_LANE or geom.num_rx == 4:
        return 0
    s = _as_int16(raw, geom).reshape(geom.num_chirps, geom.num_samples, 2, 4)
    off = [i for i in range(4) if i not in geom.rx]
    return int(np.abs(s[..., off].astype(np.int32)).max())


def cube_to_raw(cube: np.ndarray, geom: FrameGeometry) -> bytes:
    """Inverse of raw_to_cube: int16-valued complex (loops, virtual, samples) -> raw frame bytes.

    Values are rounded and clipped to int16; disabled 4-lane RX lanes are zeros.
    """
    C, N, R = geom.num_chirps, geom.num_samples, geom.num_rx
    if cube.shape != (geom.num_loops, geom.num_virtual, N):
        raise ValueError(f"cube shape {cube.shape} != {(geom.num_loops, geom.num_virtual, N)}")
    c = cube.reshape(C, R, N)
    iq = np.stack([c.real, c.imag], axis=-1)  # C, R, N, 2
    if geom.iq_swap:
        iq = iq[..., ::-1]
    iq = np.clip(np.rint(iq), -32768, 32767).astype("<i2")
    if geom.layout is RawLayout.FOUR_LANE:
        s = np.zeros((C, N, 2, 4), dtype="<i2")
        s[:, :, :, list(geom.rx)] = iq.transpose(0, 2, 3, 1)
    else:
        s = iq.reshape(C, R, N // 2, 2, 2).transpose(0, 1, 2, 4, 3)  # -> C, R, pair, I/Q, even/odd
    return np.ascontiguousarray(s).tobytes()
