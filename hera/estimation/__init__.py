"""hera.estimation: Kalman filters (KF, EKF, UKF) on variadic observation blocks.

A fusion model builds one block per sample present this step (thesis listing 4.1)::

    obs = Observations()
    obs.add("gyro", [gz], H=H_gyro, R=0.005)
    obs.add("sonar1", [r1], h=range_to(p1), jacobian=range_jac(p1), R=0.0625)
    ekf.predict(dt)
    result = ekf.update(obs, gate=0.999)   # result.accepted, result.rejected, result.nis

Angles and quaternions: a block's ``residual`` (``angle_residual``) and UKF ``mean``
(``circular_mean``), the filters' ``residual_x`` and the UKF's ``x_mean`` (``make_residual``,
``make_mean``). Covariances are checked where they enter (``as_covariance``). Post-processing:
``record(filt)`` keeps every step, ``smooth(history)`` runs the RTS smoother over it,
``batch_filter`` filters a whole array of measurements; ``update(..., details=True)`` gives
y, S, K and the log-likelihood.

Backends: with numba installed (``hera-fusion[fast]``) the hot path runs compiled kernels,
else numpy; ``HERA_ESTIMATION_BACKEND=numpy|numba|auto``, ``set_backend`` (now) or
``prefer`` (at the first filter) chooses, ``active_backend()`` tells, ``warmup()``
compiles/loads the kernels up front. A model written as numba functions runs its whole EKF
step in one compiled call: ``CompiledExtendedKalmanFilter(x0, P0, compile_model(f, F, h, H),
Q, R).fuse(dt, z)``.
"""

from . import backend
from .backend import active_backend, prefer, set_backend, warmup
from .compiled import CompiledExtendedKalmanFilter, CompiledModel, compile_model
from .correction import linearised_update
from .ekf import ExtendedKalmanFilter
from .gating import chi2_cdf, chi2_ppf, chi2_sf, gate_threshold
from .health import HealthMonitor, NisStats
from .history import StepHistory, batch_filter, record
from .kalman import KalmanFilter
from .means import circular_mean, make_mean, make_residual, quaternion_mean
from .mixtures import bhattacharyya, mixture
from .numerics import (
    CovarianceError,
    NonFiniteInputError,
    as_covariance,
    assert_positive_definite,
    joseph_update,
    numerical_jacobian,
    symmetrise,
)
from .observations import Block, Observations
from .orientation import (
    align_sign,
    angle_residual,
    matrix_to_quat,
    nearest_branch,
    quat_conjugate,
    quat_multiply,
    quat_normalize,
    quat_omega,
    quat_to_matrix,
    wrap_angle,
)
from .results import BlockOutcome, UpdateDetails, UpdateResult
from .smoother import Smoothed, rts_smoother, smooth
from .state import NoiseRate
from .ukf import MerweSigmaPoints, UnscentedKalmanFilter

__all__ = [
    "CompiledExtendedKalmanFilter",
    "CompiledModel",
    "compile_model",
    "active_backend",
    "backend",
    "prefer",
    "set_backend",
    "warmup",
    "Block",
    "BlockOutcome",
    "CovarianceError",
    "ExtendedKalmanFilter",
    "HealthMonitor",
    "KalmanFilter",
    "MerweSigmaPoints",
    "NisStats",
    "NoiseRate",
    "NonFiniteInputError",
    "Observations",
    "Smoothed",
    "StepHistory",
    "UnscentedKalmanFilter",
    "UpdateDetails",
    "UpdateResult",
    "align_sign",
    "angle_residual",
    "as_covariance",
    "assert_positive_definite",
    "batch_filter",
    "bhattacharyya",
    "circular_mean",
    "chi2_cdf",
    "chi2_ppf",
    "chi2_sf",
    "gate_threshold",
    "joseph_update",
    "linearised_update",
    "make_mean",
    "make_residual",
    "matrix_to_quat",
    "mixture",
    "nearest_branch",
    "numerical_jacobian",
    "quat_conjugate",
    "quat_multiply",
    "quat_normalize",
    "quat_omega",
    "quat_to_matrix",
    "quaternion_mean",
    "record",
    "rts_smoother",
    "smooth",
    "symmetrise",
    "wrap_angle",
]
