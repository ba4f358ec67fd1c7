"""AWR2243 / xWR raw ADC capture over the DCA1000EVM and our own radar signal processing.

Modules
    protocol   command/response and data packet wire records (ti_formats.md 1b)
    control    UDP control client, port 4096 (responses checked, timeouts, retries)
    assembler  frame reassembly from data packets (loss, reorder, duplicates, zero-fill, flags)
    receiver   UDP data receiver, port 4098 (4 MiB SO_RCVBUF, recvmmsg batches on Linux)
    mmsg       recvmmsg/sendmmsg through ctypes
    layout     4-lane interleaved / 2-lane raw ADC -> (loops, virtual channels, samples) cube
    rawfile    mmWave Studio / DCA1000 CLI *_Raw_*.bin reader (whole frames or a clear error)
    antenna    antenna layouts (positions in lambda/2, radar frame)
    dsp        range/Doppler FFT, clutter removal, CA/OS 2D CFAR, TDM-MIMO compensation, angles
    synth      FMCW raw-ADC synthesiser of point targets and vehicles (scatterers per cell)
    angle_study  DSP angle errors per SNR band vs the simulator's model (mmatch dsp --angle-study)
    fake       fake DCA1000 on 127.0.0.1 (control + paced stream with seeded loss/reordering)
    bench      `mmatch bench` suite "dsp"

Live capture (the AWR2243 itself is configured over SPI by mmWave Studio / mmwavelink)::

    cfg = drivers.ti.cfg.load_cfg("awr2243.cfg")
    geom, dsp = make_dsp(cfg, "4lane")                      # drivers.dca1000.dsp
    with DataReceiver(FrameAssembler(geom.frame_bytes)) as rx, Dca1000Control() as ctl:
        ctl.setup()                                         # connect, version, FPGA + packet config
        ctl.start_record()
        for frame in rx.frames():                           # AdcFrame: index, data, complete
            if frame.complete:
                points = dsp.process(raw_to_cube(frame.data, geom)).points   # (N, 5)

Offline: `mmatch dsp --cfg awr2243.cfg --adc adc_data_Raw_0.bin --json points.json`.
Use one FrameAssembler per recording (sequence numbers restart at RECORD_START).
Raw (not multi/"hdr") LVDS mode only; 16-bit complex 1x samples.
"""
