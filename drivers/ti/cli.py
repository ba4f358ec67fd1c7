"""The TI CLI-port configuration entry point under the name other packages look for.

`send_cfg(cli_port, cfg_or_path)` is `mmatch.drivers.ti.config_sender.send_cfg`.
"""

from mmatch.drivers.ti.config_sender import CommandReply, RadarConfigError, send_cfg

__all__ = ["send_cfg", "CommandReply", "RadarConfigError"]
