"""Run metrics of paper 000 (simulator-vs-real particle-filter comparison), pure numpy.

All functions take a particle cloud as ``(N, d)`` positions (d = 2 in the paper: x, y) with optional
weights ``(N,)``; weights are normalised here (eq. 7-8). They describe the evolution of a filter, not its
error, so two runs of the same flight can be compared even though the particles are random.

- :func:`total_variance`  eq. 13: ``varT(P) = sqrt(cov(x,x)^2 + cov(y,y)^2)``
- :func:`gaussian_entropy` eq. 15: ``H(Pp) = 1 + log(2 pi) + 1/2 log|Sigma|`` (2-D Gaussian, nats);
  for d dimensions the same formula reads ``d/2 (1 + log 2 pi) + 1/2 log|Sigma|``
- :func:`kl_divergence` eq. 16: ``D_KL(P||Q)`` between the Gaussians fitted to two clouds.
"""

from __future__ import annotations

import numpy as np

__all__ = ["weighted_mean_cov", "total_variance", "total_variance_from_cov", "gaussian_entropy", "entropy_from_cov",
           "kl_divergence", "kl_gaussian"]


def weighted_mean_cov(points: np.ndarray, weights: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Mean ``(d,)`` and covariance ``(d, d)`` of a (weighted) particle cloud ``(N, d)``.

    The covariance is the weighted population covariance ``sum w_i (p_i - mu)(p_i - mu)^T`` with
    ``sum w_i = 1``, i.e. the covariance of the distribution the particles represent (paper 000 eq. 5).
    """
    p = np.asarray(points, dtype=float)
    if p.ndim == 1:
        p = p[:, None]
    if p.shape[0] == 0:
        raise ValueError("empty particle cloud")
    if weights is None:
        w = np.full(p.shape[0], 1.0 / p.shape[0])
    else:
        w = np.asarray(weights, dtype=float)
        if w.shape != (p.shape[0],):
            raise ValueError(f"weights shape {w.shape} does not match {p.shape[0]} particles")
        if np.any(w < 0) or not np.isfinite(w).all():
            raise ValueError("weights must be finite and >= 0")
        s = w.sum()
        if s <= 0:
            raise ValueError("weights sum to zero")
        w = w / s
    # einsum rather than BLAS ``@``: multithreaded OpenBLAS stalls on a loaded machine for long vectors
    mu = np.einsum("i,ij->j", w, p)
    dev = p - mu
    cov = np.einsum("ij,ik->jk", dev * w[:, None], dev)
    return mu, cov


def total_variance(points: np.ndarray, weights: np.ndarray | None = None) -> float:
    """Paper 000 eq. 13: ``sqrt(cov(x,x)^2 + cov(y,y)^2)`` (m^2) of the first two coordinates."""
    _, cov = weighted_mean_cov(np.asarray(points)[:, :2], weights)
    return total_variance_from_cov(cov)


def total_variance_from_cov(cov: np.ndarray) -> float:
    """Paper 000 eq. 13 from a cloud's covariance (first two axes)."""
    return float(np.hypot(cov[0, 0], cov[1, 1]))


def _logdet(cov: np.ndarray) -> float:
    sign, logdet = np.linalg.slogdet(cov)
    if sign <= 0:
        return -np.inf
    return float(logdet)


def gaussian_entropy(points: np.ndarray, weights: np.ndarray | None = None, dims: int = 2) -> float:
    """Paper 000 eq. 15: differential entropy (nats) of the Gaussian fitted to the cloud's first ``dims`` axes.

    For d = 2 this is ``1 + log(2 pi) + 1/2 log|Sigma|``. A degenerate cloud (all particles on one point
    or a line) has ``|Sigma| = 0`` and entropy ``-inf``.
    """
    _, cov = weighted_mean_cov(np.asarray(points)[:, :dims], weights)
    return entropy_from_cov(cov)


def entropy_from_cov(cov: np.ndarray) -> float:
    """Paper 000 eq. 15 from a covariance (d x d): ``d/2 (1 + log 2 pi) + 1/2 log|Sigma|`` nats."""
    d = cov.shape[0]
    return float(0.5 * d * (1.0 + np.log(2 * np.pi)) + 0.5 * _logdet(cov))


def kl_gaussian(mu1: np.ndarray, cov1: np.ndarray, mu2: np.ndarray, cov2: np.ndarray) -> float:
    """``D_KL(N(mu1, cov1) || N(mu2, cov2))`` in nats (paper 000 eq. 16, d-dimensional).

    ``1/2 (mu2-mu1)^T S2^-1 (mu2-mu1) + 1/2 tr(S2^-1 S1) - 1/2 ln(|S1|/|S2|) - d/2``.
    Returns ``inf`` when either covariance is singular (a converged cloud against a spread one).
    """
    mu1, mu2 = np.atleast_1d(mu1).astype(float), np.atleast_1d(mu2).astype(float)
    cov1, cov2 = np.atleast_2d(cov1).astype(float), np.atleast_2d(cov2).astype(float)
    d = mu1.size
    ld1, ld2 = _logdet(cov1), _logdet(cov2)
    if not (np.isfinite(ld1) and np.isfinite(ld2)):
        return float("inf")
    dm = mu2 - mu1
    s2inv_dm = np.linalg.solve(cov2, dm)
    tr = np.trace(np.linalg.solve(cov2, cov1))
    return float(0.5 * dm @ s2inv_dm + 0.5 * tr - 0.5 * (ld1 - ld2) - 0.5 * d)


def kl_divergence(p_points: np.ndarray, q_points: np.ndarray, p_weights: np.ndarray | None = None,
                  q_weights: np.ndarray | None = None, dims: int = 2) -> float:
    """Paper 000 eq. 16: KL divergence of cloud P from reference cloud Q (Gaussian fits, first ``dims`` axes)."""
    mu1, c1 = weighted_mean_cov(np.asarray(p_points)[:, :dims], p_weights)
    mu2, c2 = weighted_mean_cov(np.asarray(q_points)[:, :dims], q_weights)
    return kl_gaussian(mu1, c1, mu2, c2)
