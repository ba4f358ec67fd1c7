"""The running system: config, per-vehicle loop, Zenoh transport, logging, replay, CLI."""
