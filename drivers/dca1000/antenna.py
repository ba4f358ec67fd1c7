"""Antenna layouts: TX and RX phase-centre positions in half-wavelengths, radar frame.

Positions are (x, z): x right, z up, in units of lambda/2 at the chirp's centre frequency.
A target in direction u = (sin(az) cos(el), cos(az) cos(el), sin(el)) reaches virtual channel
(tx, rx) over a path shorter by (p_tx + p_rx) . u, i.e. with baseband phase -pi * (x u_x + z u_z)
relative to the origin (the synthesiser and the DSP both use this model).

AWR2243BOOST (same array as AWR1843BOOST), in virtual-antenna index order: RX0-RX3 a
lambda/2 apart, TX2 2 lambda from TX0 (TX0 + TX2 = an 8-element azimuth array), TX1 between
them and raised by lambda/2 (4 elevation channels). xWR16xxBOOST: TX0 and TX1 2 lambda apart,
no elevation. The index runs towards -x (x = -index), which is the geometry under which TI's
mmw demo AoA (x = range * Wx with Wx = 2 k / N from the azimuth FFT peak k over the channels
in index order; Wz = arg(Az * conj(El)) / pi + 2 Wx) is right for our phase model: our raw
path then gives the same x and z signs as the chip's own UART point cloud
(tests/dca1000/test_dsp.py::test_angles_match_ti_demo_formulas). `mirror_x` flips a layout
for a board that turns out to be wired or mounted the other way (check once with a corner
reflector).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mmatch.errors import ConfigError


@dataclass(frozen=True)
class AntennaLayout:
    """TX/RX positions (x, z) in half-wavelengths, indexed by TX / RX number."""

    name: str
    tx: tuple[tuple[float, float], ...]
    rx: tuple[tuple[float, float], ...]

    def virtual_positions(self, tx_order: tuple[int, ...], rx: tuple[int, ...]) -> np.ndarray:
        """float64 (slots * len(rx), 2) positions of the virtual channels, in cube order."""
        for t in tx_order:
            if not 0 <= t < len(self.tx):
                raise ConfigError(f"layout {self.name} has no TX{t}")
        for r in rx:
            if not 0 <= r < len(self.rx):
                raise ConfigError(f"layout {self.name} has no RX{r}")
        t = np.asarray([self.tx[i] for i in tx_order], dtype=np.float64)
        r = np.asarray([self.rx[i] for i in rx], dtype=np.float64)
        return (t[:, None, :] + r[None, :, :]).reshape(-1, 2)

    def mirror_x(self) -> "AntennaLayout":
        """The same array seen with x reversed (for a board mounted or wired the other way)."""
        flip = lambda ps: tuple((-x, z) for x, z in ps)  # noqa: E731
        return AntennaLayout(self.name + "-mirrored", flip(self.tx), flip(self.rx))


AWR2243BOOST = AntennaLayout(
    name="AWR2243BOOST",
    tx=((0.0, 0.0), (-2.0, 1.0), (-4.0, 0.0)),
    rx=((0.0, 0.0), (-1.0, 0.0), (-2.0, 0.0), (-3.0, 0.0)),
)

XWR16XXBOOST = AntennaLayout(
    name="xWR16xxBOOST",
    tx=((0.0, 0.0), (-4.0, 0.0)),
    rx=((0.0, 0.0), (-1.0, 0.0), (-2.0, 0.0), (-3.0, 0.0)),
)
"""IWR/AWR1642BOOST: two TX 2 lambda apart -> 8-element azimuth array, no elevation."""

LAYOUTS: dict[str, AntennaLayout] = {
    "awr2243boost": AWR2243BOOST,
    "awr1843boost": AntennaLayout("AWR1843BOOST", AWR2243BOOST.tx, AWR2243BOOST.rx),
    "xwr16xxboost": XWR16XXBOOST,
}
