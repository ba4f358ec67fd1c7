"""The running system: config, per-vehicle loop, Zenoh transport, logging, replay, CLI.

config     the typed vehicle config (TOML; unknown keys, wrong types, impossible values refused)
keys       Zenoh key expressions (mmatch/v1/<vehicle>/shared|fused|health)
transport  one Zenoh session per process; keep-newest queues; bad payloads dropped and counted
sources    radar (uart, dca1000, replay, sim) and camera (opencv, oak, replay, sim, none) backends
node       per-frame CAV and Ego logic (pairing by capture time, several CAVs, link loss)
loop       reader thread per sensor, bounded queues, health, clean stop
recorder   chunked, rotated MCAP field logs with a free-disk floor; logreader reads up to a break
logschema  log topics and records (Foxglove protobuf schemas; raw device bytes schema-less)
replay     logs and raw UART captures back through the Node
health     systemd notify (READY, WATCHDOG, STATUS) without dependencies
pipeline   the per-frame pipeline contract (process_view, codec, fuse)
"""
