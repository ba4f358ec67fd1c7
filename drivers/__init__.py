"""Hardware I/O: TI radars (UART TLV, DCA1000 raw ADC + DSP), cameras and detectors.

Produces mmatch types; knows no pipeline. Imports go edge -> drivers -> mmatch.
"""
