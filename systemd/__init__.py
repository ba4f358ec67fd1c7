"""Data only: the systemd unit of the vehicle service and its install notes. Installed as
package data under `mmatch.systemd`; read with `mmatch.edge.resources`."""
