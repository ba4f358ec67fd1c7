"""AWR2243 / xWR raw ADC capture over the DCA1000EVM and our own radar signal processing.

protocol   command/response and data packet wire records
control    UDP control client (port 4096)
assembler  frame reassembly from data packets (loss, reorder, zero-fill, flags)
receiver   UDP data receiver (port 4098)
layout     4-lane / 2-lane raw ADC layouts -> (loops, virtual channels, samples) cube
rawfile    mmWave Studio / DCA1000 CLI *_Raw_*.bin reader
antenna    antenna layouts; dsp: range/Doppler/CFAR/angle; synth: FMCW synthesiser
fake       fake DCA1000 on 127.0.0.1; bench: `mmatch bench` suite "dsp"
"""
