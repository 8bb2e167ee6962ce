"""Standard errors that survive correlated residuals (cluster-robust sandwich).

Step-response residuals are not independent: a wrong inertia or latency leaves the same sign
over the whole transient, so the textbook covariance (J'WJ)^-1 of a weighted least-squares fit
counts every 30 ms sample as new evidence and its standard errors come out several times too
small. The sandwich (J'WJ)^-1 [sum_c (J_c' r_c)(J_c' r_c)'] (J'WJ)^-1 over clusters c that are
independent of each other (diagnosis's CV groups: a run step, or a 2 s block of a step-response
run) lets the residuals correlate freely inside a cluster (Liang & Zeger 1986; the block
analogue of Newey-West). With G clusters it is scaled by G / (G - 1), and it is never reported
below the textbook value (a sandwich from few clusters can come out small by chance).
"""

from __future__ import annotations

import numpy as np

MIN_CLUSTERS_PER_PARAM = 2  # fewer clusters than this many per parameter: textbook SEs only


def cluster_se(Jw: np.ndarray, rw: np.ndarray, clusters: np.ndarray) -> np.ndarray:
    """Cluster-robust standard errors of a weighted least-squares fit, in the units of J's
    columns: `Jw` (n, p) weighted Jacobian d prediction / d parameter, `rw` (n,) weighted
    residuals (measured - predicted), `clusters` (n,) labels of independent blocks. Returns
    max(textbook, sandwich) per parameter (textbook alone when there are too few clusters)."""
    Jw = np.asarray(Jw, dtype=float)
    rw = np.asarray(rw, dtype=float)
    n, p = Jw.shape
    bread = np.linalg.pinv(Jw.T @ Jw)
    textbook = np.sqrt(np.maximum(np.diag(bread), 0.0))
    labels, inv = np.unique(np.asarray(clusters).astype(str), return_inverse=True)
    G = len(labels)
    if p == 0 or G < max(2, MIN_CLUSTERS_PER_PARAM * p):
        return textbook
    scores = np.zeros((G, p))
    np.add.at(scores, inv, Jw * rw[:, None])  # J_c' r_c per cluster
    meat = scores.T @ scores * G / (G - 1)
    # scale: the textbook covariance assumes unit-variance weighted residuals; the sandwich uses
    # the residuals themselves, so a group noise scale that is off cancels out
    cov = bread @ meat @ bread
    return np.maximum(textbook, np.sqrt(np.maximum(np.diag(cov), 0.0)))
