"""CAV-side processing of one radar frame plus camera detections (DESIGN.md "The per-frame flow").

Stages: `egomotion` (Doppler fit, stationary vs moving), `frustum` (camera-box separation),
`clustering` (DBSCAN per vehicle), `background` (DBSCAN + voxel sketch); `process` chains
them into a `mmatch.shared.SharedFrame`. Settings live in `config`.
"""
