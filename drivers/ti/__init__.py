"""TI mmWave radars over UART: TLV frame decoding, streaming, writing, and CLI configuration.

Reference: /work/shared/ti_formats.md (section 0: what a frame is; 1a: layouts; 1c: .cfg).

Public API (import from the submodules; this package imports nothing heavy):

    drivers.ti.writer.encode_frame(points, frame_number, fmt="sdk3", *, side_info=None,
                                   noise_db=0.0, empty_tlv1="omit", q_format=None, chirp=None,
                                   units=DEFAULT_UNITS, extra_tlvs=(), version=None,
                                   platform=None, time_cpu_cycles=0, sub_frame_number=0,
                                   header_fields=None) -> bytes
        One float32 (N, 5) point array (x, y, z m, doppler m/s, snr dB; radar frame) -> one
        byte-exact UART packet. fmt: "sdk3" (40-B header, float TLV 1 + TLV 7 side info,
        32-B padding), "sdk2"/"sdk1" (40-B header, Q-format TLV 1, no SNR on the wire),
        "xwr14xx" (36-B header, Q-format), "toolbox" (40-B header, TLV 1020 compressed
        spherical points), "pc3d" (48-B people-counting header with checksum, TLV 6, TLV
        lengths including the TLV header, unpadded). `chirp` (a cfg's ChirpParams) gives
        Q-format range/Doppler indices; `extra_tlvs` appends any TLV messages (drivers.ti.tlv).
    drivers.ti.writer.encode_stream(point_arrays, fmt="sdk3", first_frame=1, **options) -> bytes
        Consecutive frames as one serial stream, e.g. to feed simulated points through the
        real UART path (SerialSource("loop://"), a pty, or TlvReader.feed).
    drivers.ti.writer.expected_points(points, fmt="sdk3", ...) -> float32 (N, 5)
        Exactly what the decoder returns for those points in that format (quantisation).
    drivers.ti.decoder.decode_frame(buf, offset=0, end=None, *, final=True) -> DecodeResult
        Pure: the frame at `offset` -> TiPacket (header, TLV messages, points;
        `.radar_frame()`), or a rejection reason, or "need more".
    drivers.ti.reader.TlvReader(source=None, on_error="log", chirp=None)
        Incremental reader: `feed(bytes) -> [TiPacket]`, `finish()`, or over a ByteSource
        `packets()`, `frames()` (mmatch RadarFrame), `read_frame(timeout)`. Never raises on
        garbage (unless on_error="raise"); `stats`: frames, bytes_skipped, rejected by reason
        (+ offsets), tlv_types, unknown_tlvs, restarts, frame_gaps.
    drivers.ti.sources.open_source(spec)  "/dev/ttyACM1", "loop://", "socket://...",
        "file:PATH", "file:PATH?pace=frames&period=0.05", "file:PATH?pace=baud".
    drivers.ti.cfg.parse_cfg/load_cfg     .cfg -> RadarCfg(ChirpParams) (shared contract).
    drivers.ti.config_sender.send_cfg(port, cfg_or_path)  line-by-line CLI configuration
        (also importable as drivers.ti.cli.send_cfg).
    drivers.ti.simulator.SimulatedRadar(points_fn, fmt="sdk3", speed=1.0)
        A TI EVM without hardware: `cli_port` and `data_port` ptys; after the cfg's
        sensorStart it streams encode_frame(points_fn(frame_number)) every frame period.
"""
