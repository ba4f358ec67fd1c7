"""Data only: example vehicle configs, Zenoh configs, TI radar chirp profiles (radar/) and an
example camera calibration (camera/). Installed as package data under `mmatch.cfg`; read with
`mmatch.edge.resources`."""
