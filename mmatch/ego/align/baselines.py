"""Point-cloud registration peers as aligners: Open3D ICP, FGR and RANSAC on FPFH, small_gicp GICP.

The paper's comparison: general-purpose registration on the same radar data, without
co-visible vehicles. Each peer gets every point both shared frames carry (vehicle points
and background sketch, the same bytes MMatch gets), flattened onto the road plane
(x, y; z = 0: both radars sit level, the transform is SE(2)), and starts from the identity
(`o3d-icp`, `gicp`) or from features alone (`o3d-fgr`, `o3d-ransac`, then point-to-point ICP).
Features are FPFH with in-plane normals (the xy-PCA of each point's neighbours): with
z = 0, Open3D's own normals all point up and FPFH degenerates (LIBRARIES.md section 7).
Every result is projected onto SE(2) (yaw + x, y) against mirror flips; z is the mounting
height difference. Run with the `none` matcher (they find no pairs).

The libraries are the `baselines` extra and are imported inside the aligners; a missing one
raises ConfigError with the install line. Open3D is held to one thread (its TBB pool,
`open3d.utility.set_max_threads(1)`, process-wide): its times then compare with ours, and
its seeded RANSAC gives the same result on every run (with several threads it does not).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from mmatch.ego.base import AlignResult, MatchResult
from mmatch.ego.rigid import se2_to_matrix
from mmatch.errors import ConfigError
from mmatch.shared import SharedFrame

INSTALL_HINT = "pip install 'mmatch[baselines]'"
EXTRA_MODULES = {"o3d-icp": "open3d", "o3d-fgr": "open3d", "o3d-ransac": "open3d", "gicp": "small_gicp"}


def _open3d():
    try:
        import open3d as o3d
    except ImportError as exc:
        raise ConfigError(f"the Open3D baselines need open3d ({exc}): {INSTALL_HINT} "
                          "(open3d-cpu; on Debian also apt-get install libusb-1.0-0)") from exc
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    o3d.utility.set_max_threads(1)
    return o3d


def _small_gicp():
    try:
        import small_gicp
    except ImportError as exc:
        raise ConfigError(f"the gicp baseline needs small_gicp ({exc}): {INSTALL_HINT}") from exc
    return small_gicp


def missing_extra(aligner: str) -> str | None:
    """Why `aligner` cannot run here (its library does not import), or None (it can, or is not a peer)."""
    loader = {"open3d": _open3d, "small_gicp": _small_gicp}.get(EXTRA_MODULES.get(aligner, ""))
    if loader is None:
        return None
    try:
        loader()
    except ConfigError as exc:
        return str(exc)
    return None


@dataclass(frozen=True)
class PeerConfig:
    """Settings of the peers, scaled to radar density (a few hundred points over ~100 m).

    icp_max_dist_m: correspondence distance of the ICPs (and of the refinement after
    FGR / RANSAC); normal_k: neighbours of the in-plane normal; fpfh_radius_m / fpfh_max_nn:
    FPFH support; feature_dist_m: inlier distance of FGR and RANSAC.
    """

    icp_max_dist_m: float = 3.0
    icp_iterations: int = 100
    refine_dist_m: float = 1.5
    normal_k: int = 8
    fpfh_radius_m: float = 6.0
    fpfh_max_nn: int = 60
    feature_dist_m: float = 2.0
    ransac_iterations: int = 100000
    ransac_confidence: float = 0.999
    gicp_downsampling_m: float = 0.25
    seed: int = 0


def flat_cloud(frame: SharedFrame) -> np.ndarray:
    """(N, 3) float64 x, y, 0 of every shared point (vehicle points, then background), radar frame."""
    xy = np.vstack([frame.vehicle_points[:, :2], frame.background[:, :2]]).astype(np.float64)
    return np.column_stack([xy, np.zeros(len(xy))])


def in_plane_normals(xyz: np.ndarray, k: int) -> np.ndarray:
    """(N, 3) unit normals in the road plane: the minor axis of each point's k-neighbour xy spread."""
    n = len(xyz)
    if n < 3:
        return np.tile([1.0, 0.0, 0.0], (n, 1))
    _, idx = cKDTree(xyz[:, :2]).query(xyz[:, :2], k=min(k, n))
    nb = xyz[idx, :2] - xyz[idx, :2].mean(axis=1, keepdims=True)          # (N, k, 2)
    cov = np.einsum("nki,nkj->nij", nb, nb)
    _, vec = np.linalg.eigh(cov)                                           # ascending eigenvalues
    normal = vec[:, :, 0]
    return np.column_stack([normal, np.zeros(n)])


def project_se2(T: np.ndarray, own: SharedFrame, other: SharedFrame) -> np.ndarray:
    """The yaw and x, y of a 4x4 estimate as T_ego_cav; z from the two mounting heights."""
    yaw = np.arctan2(T[1, 0], T[0, 0])
    R = np.array([[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]])
    return se2_to_matrix(R, np.asarray(T[:2, 3], float), other.radar_height - own.radar_height)


class _Peer:
    name = ""

    def __init__(self, config: PeerConfig = PeerConfig()) -> None:
        self.cfg = config

    def estimate(self, src: np.ndarray, dst: np.ndarray) -> np.ndarray | None:
        raise NotImplementedError

    def __call__(self, own: SharedFrame, other: SharedFrame, match: MatchResult) -> AlignResult:
        src, dst = flat_cloud(other), flat_cloud(own)
        if len(src) < 3 or len(dst) < 3:
            return AlignResult(None, f"{min(len(src), len(dst))} shared points; registration needs 3")
        T = self.estimate(src, dst)
        if T is None or not np.all(np.isfinite(T)):
            return AlignResult(None, f"{self.name} found no transform")
        return AlignResult(project_se2(T, own, other))


class _Open3DPeer(_Peer):
    def __init__(self, config: PeerConfig = PeerConfig()) -> None:
        super().__init__(config)
        self.o3d = _open3d()

    def cloud(self, xyz: np.ndarray, normals: bool = False):
        pcd = self.o3d.geometry.PointCloud(self.o3d.utility.Vector3dVector(xyz))
        if normals:
            pcd.normals = self.o3d.utility.Vector3dVector(in_plane_normals(xyz, self.cfg.normal_k))
        return pcd

    def icp(self, src, dst, init: np.ndarray, dist: float) -> np.ndarray:
        reg = self.o3d.pipelines.registration
        res = reg.registration_icp(src, dst, dist, init, reg.TransformationEstimationPointToPoint(),
                                   reg.ICPConvergenceCriteria(max_iteration=self.cfg.icp_iterations))
        return np.asarray(res.transformation)

    def fpfh(self, pcd):
        return self.o3d.pipelines.registration.compute_fpfh_feature(
            pcd, self.o3d.geometry.KDTreeSearchParamHybrid(radius=self.cfg.fpfh_radius_m,
                                                           max_nn=self.cfg.fpfh_max_nn))


class O3DICPAligner(_Open3DPeer):
    """Open3D point-to-point ICP from the identity."""

    name = "o3d-icp"

    def estimate(self, src, dst):
        return self.icp(self.cloud(src), self.cloud(dst), np.eye(4), self.cfg.icp_max_dist_m)


class O3DFGRAligner(_Open3DPeer):
    """Open3D Fast Global Registration on FPFH (in-plane normals, seeded), refined by point-to-point ICP."""

    name = "o3d-fgr"

    def estimate(self, src, dst):
        reg, c = self.o3d.pipelines.registration, self.cfg
        s, d = self.cloud(src, normals=True), self.cloud(dst, normals=True)
        self.o3d.utility.random.seed(c.seed)
        opt = reg.FastGlobalRegistrationOption(use_absolute_scale=True, decrease_mu=True,
                                               maximum_correspondence_distance=c.feature_dist_m,
                                               iteration_number=200)
        res = reg.registration_fgr_based_on_feature_matching(s, d, self.fpfh(s), self.fpfh(d), opt)
        return self.icp(s, d, np.asarray(res.transformation), c.refine_dist_m)


class O3DRansacAligner(_Open3DPeer):
    """Open3D RANSAC on FPFH correspondences (in-plane normals, seeded), refined by point-to-point ICP."""

    name = "o3d-ransac"

    def estimate(self, src, dst):
        reg, c = self.o3d.pipelines.registration, self.cfg
        s, d = self.cloud(src, normals=True), self.cloud(dst, normals=True)
        self.o3d.utility.random.seed(c.seed)
        checkers = [reg.CorrespondenceCheckerBasedOnEdgeLength(0.9),
                    reg.CorrespondenceCheckerBasedOnDistance(c.feature_dist_m)]
        res = reg.registration_ransac_based_on_feature_matching(
            s, d, self.fpfh(s), self.fpfh(d), True, c.feature_dist_m,
            reg.TransformationEstimationPointToPoint(False), 3, checkers,
            reg.RANSACConvergenceCriteria(c.ransac_iterations, c.ransac_confidence))
        return self.icp(s, d, np.asarray(res.transformation), c.refine_dist_m)


class GICPAligner(_Peer):
    """small_gicp Generalized-ICP from the identity (one thread)."""

    name = "gicp"

    def __init__(self, config: PeerConfig = PeerConfig()) -> None:
        super().__init__(config)
        self.sg = _small_gicp()

    def estimate(self, src, dst):
        c = self.cfg
        res = self.sg.align(dst, src, np.eye(4), registration_type="GICP",
                            downsampling_resolution=c.gicp_downsampling_m,
                            max_correspondence_distance=c.icp_max_dist_m, num_threads=1,
                            max_iterations=c.icp_iterations)
        return np.asarray(res.T_target_source)
