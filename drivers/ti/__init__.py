"""TI mmWave radars over UART: TLV frame decoding, streaming, writing, and CLI configuration.

Reference: /work/shared/ti_formats.md (section 0: what a frame is; 1a: layouts; 1c: .cfg).

Public API (import from the submodules; this package imports nothing heavy):

    drivers.ti.writer.encode_frame(points, frame_number, fmt="sdk3", *, platform=None,
                                   version=None, snr=True, extra_tlvs=(), ...) -> bytes
        Turn one float32 (N, 5) point array (x, y, z, doppler m/s, snr dB; radar frame) into
        one byte-exact UART packet of the given format: "sdk3" (40-B header, float TLV 1 +
        TLV 7 side info, 32-B padding), "sdk2" (40-B header, Q-format TLV 1), "xwr14xx"
        (36-B header, SDK 1.x/2.x Q-format), "pc3d" (48-B people-counting header with
        checksum, compressed spherical TLV 6, unpadded). Feed a sequence of frames through
        `encode_stream(frames, fmt=...)` to get a serial stream for the real reader.
    drivers.ti.decoder.decode_frame(buf, offset=0, end=None) -> DecodeResult
        Pure: one frame at `offset` -> RadarFrame + TLVs, or a rejection reason, or "need more".
    drivers.ti.reader.TlvReader(source, on_error="log")
        Incremental reader over any byte source (serial, capture file, loop://, pty); never
        raises on garbage; counters of frames accepted, bytes skipped, rejections by reason.
    drivers.ti.sources.open_source(url)   serial device, "file:PATH[?pace=recorded]", "loop://".
    drivers.ti.cfg.parse_cfg/load_cfg     .cfg -> RadarCfg(ChirpParams) (shared contract).
    drivers.ti.config_sender.send_cfg(port, cfg)   line-by-line CLI configuration.
"""
