"""Arrow-structured normal equations, shared by the paper's LM, varpro and the Fisher information."""

from __future__ import annotations

import numpy as np

# --------------------------------------------------------------------------
# Arrow-structured normal equations (shared with varpro and fisher)
# --------------------------------------------------------------------------
#
# Every residual depends on the light's two tangent coordinates (a, b) and on
# its own point's two parameters (albedo or log albedo, and k). J^T W J is
# therefore an "arrow": a 2x2 light block V, a 2x2 block U_p per point and a
# 2x2 coupling W_p per point (rows a, b; columns the point's two parameters),
# zero elsewhere. Blocks are passed as tuples of their distinct entries so
# that per-point values are flat (m,) arrays: V = (v_aa, v_ab, v_bb),
# U = (u_11, u_12, u_22), W = (w_a1, w_a2, w_b1, w_b2).


def _schur_complement(light_block, point_blocks, couplings):
    """The pieces both arrow-system functions need (call inside ``np.errstate``).

    Returns each point's ``U_p^-1`` as ``(i11, i12, i22)``, ``Y_p = W_p U_p^-1``
    as ``(y_a1, y_a2, y_b1, y_b2)`` (rows: the light's a, b; columns: the
    point's two parameters) and the Schur complement ``S = V - sum_p Y_p
    W_p^T`` as ``(s_aa, s_ab, s_bb)``.
    """
    v_aa, v_ab, v_bb = light_block
    u_11, u_12, u_22 = point_blocks
    w_a1, w_a2, w_b1, w_b2 = couplings
    det = u_11 * u_22 - u_12 * u_12
    i11, i22, i12 = u_22 / det, u_11 / det, -u_12 / det
    y_a1 = w_a1 * i11 + w_a2 * i12
    y_a2 = w_a1 * i12 + w_a2 * i22
    y_b1 = w_b1 * i11 + w_b2 * i12
    y_b2 = w_b1 * i12 + w_b2 * i22
    s_aa = v_aa - float(np.sum(y_a1 * w_a1 + y_a2 * w_a2))
    s_ab = v_ab - float(np.sum(y_a1 * w_b1 + y_a2 * w_b2))
    s_bb = v_bb - float(np.sum(y_b1 * w_b1 + y_b2 * w_b2))
    return (i11, i12, i22), (y_a1, y_a2, y_b1, y_b2), (s_aa, s_ab, s_bb)


def solve_arrow_system(light_block, point_blocks, couplings, light_gradient, point_gradient):
    """Solve ``[[V, W], [W^T, U]] [d_light; d_point] = -[g_light; g_point]`` by the Schur complement.

    ``light_block`` = (v_aa, v_ab, v_bb) floats, ``point_blocks`` = (u_11,
    u_12, u_22) and ``couplings`` = (w_a1, w_a2, w_b1, w_b2) arrays (m,),
    ``light_gradient`` = (g_a, g_b), ``point_gradient`` = (g_1, g_2) arrays (m,).
    Damping, if any, is already added to the diagonals by the caller. The
    point blocks are eliminated (S = V - sum_p W_p U_p^-1 W_p^T), the 2x2
    light system solved, and each point's step back-substituted:
    ``U_p d_p = -g_p - W_p^T d_light``. O(m); returns ``(step_light (2,),
    step_1 (m,), step_2 (m,))``, non-finite where a block is singular.
    """
    w_a1, w_a2, w_b1, w_b2 = couplings
    g_a, g_b = light_gradient
    g_1, g_2 = point_gradient
    with np.errstate(divide="ignore", invalid="ignore"):
        (i11, i12, i22), (y_a1, y_a2, y_b1, y_b2), (s_aa, s_ab, s_bb) = _schur_complement(light_block, point_blocks, couplings)
        # The Schur complement's right-hand side.
        rhs_a = -g_a + float(np.sum(y_a1 * g_1 + y_a2 * g_2))
        rhs_b = -g_b + float(np.sum(y_b1 * g_1 + y_b2 * g_2))
        s_det = s_aa * s_bb - s_ab * s_ab
        step_a = (s_bb * rhs_a - s_ab * rhs_b) / s_det
        step_b = (s_aa * rhs_b - s_ab * rhs_a) / s_det
        # Back-substitute each point's step: U_p d_p = -g_p - W_p^T d_light.
        q_1 = -g_1 - w_a1 * step_a - w_b1 * step_b
        q_2 = -g_2 - w_a2 * step_a - w_b2 * step_b
        return np.array([step_a, step_b]), i11 * q_1 + i12 * q_2, i12 * q_1 + i22 * q_2


def arrow_covariance(light_block, point_blocks, couplings):
    """Inverse of an arrow-structured ``J^T W J``: the light block and each point's marginal 2x2 block.

    Same block arguments as :func:`solve_arrow_system` (undamped). With
    ``S = V - sum_p W_p U_p^-1 W_p^T`` the light covariance is ``S^-1`` and
    point p's marginal covariance ``U_p^-1 + Y_p^T S^-1 Y_p`` with ``Y_p =
    W_p U_p^-1``: its own uncertainty plus what the light's uncertainty
    passes on to it. With weights ``1/sigma_j**2`` in J^T W J this is the
    Gauss-Newton covariance of the weighted least-squares estimate (and, at
    the true parameters, the Cramer-Rao bound).

    Returns ``(light_cov (2, 2), var_1 (m,), var_2 (m,), cov_12 (m,))``.
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        (i11, i12, i22), (y_a1, y_a2, y_b1, y_b2), (s_aa, s_ab, s_bb) = _schur_complement(light_block, point_blocks, couplings)
        light_cov = np.linalg.inv(np.array([[s_aa, s_ab], [s_ab, s_bb]]))
        c_aa, c_ab, c_bb = light_cov[0, 0], light_cov[0, 1], light_cov[1, 1]
        var_1 = i11 + c_aa * y_a1 * y_a1 + 2.0 * c_ab * y_a1 * y_b1 + c_bb * y_b1 * y_b1
        var_2 = i22 + c_aa * y_a2 * y_a2 + 2.0 * c_ab * y_a2 * y_b2 + c_bb * y_b2 * y_b2
        cov_12 = i12 + c_aa * y_a1 * y_a2 + c_ab * (y_a1 * y_b2 + y_b1 * y_a2) + c_bb * y_b1 * y_b2
    return light_cov, var_1, var_2, cov_12
