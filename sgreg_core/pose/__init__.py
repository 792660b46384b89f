"""Robust pose estimation (paper section V, after G3Reg): NMS, closed-form fits, GNC-TLS,
maximum-clique pyramid, cloud verification, and the `estimate_pose` verdict."""
from .clique import CliqueResult, clique_pyramid, compatibility, length_residuals, max_clique
from .estimator import PoseConfig, PoseResult, estimate_pose
from .gnc import GncConfig, GncResult, gnc_tls
from .nms import nms_correspondences
from .solvers import RigidFit, apply_T, fit_rigid, make_T, residuals
from .verify import CloudVerifier, Footprint, ReferenceCloud, Verification, finite_voxel_downsample

__all__ = [
    "CliqueResult", "CloudVerifier", "Footprint", "GncConfig", "GncResult", "PoseConfig", "PoseResult",
    "ReferenceCloud", "RigidFit", "Verification", "apply_T", "clique_pyramid", "compatibility", "estimate_pose",
    "fit_rigid", "gnc_tls", "length_residuals", "make_T", "max_clique", "nms_correspondences",
    "residuals", "finite_voxel_downsample",
]
