"""Dot-product kernel on poses (paper eq. 22, 18; docs/method.md §6).

    k(g_i, g_j) = σf² · (ρ1 · r_i·r_j + (1 − ρ1) · t_i·t_j)

with the paper's inner product ⟨g_i, g_j⟩ = r_i·r_j + t_i·t_j (eq. 18) weighted like eq. 19 and scaled
by σf² (σf = 1 and ρ1 = ½ give the paper's kernel up to a factor 2). The paper's σ0² δij is the noise
variance, which the GP adds. Positive semi-definite (a Gram matrix of weighted inner products), but the
rotation vector jumps at θ = π, so this kernel is discontinuous there (docs/method.md §2).

∂K/∂log σf = 2 K;   ∂K/∂log ρ1 = σf² ρ1 (R − T) with R = r_i·r_j, T = t_i·t_j.
"""

from __future__ import annotations

import numpy as np

from rbgp_cli.kernels.base import Hyperparameter, Kernel, fdot, output_scale

__all__ = ["DotProduct"]


class DotProduct(Kernel):
    """σf² (ρ1 r_i·r_j + (1−ρ1) t_i·t_j); X has shape (n, k + 3), rotation coordinates first."""

    kind = "dot_product"
    #: a weighted sum of inner products: a Gram matrix ZᵀZ, positive semi-definite
    positive_semidefinite = True

    def __init__(self, rotation_dims: int = 3, rho_rot: float = 0.5, learn_rho: bool = False):
        if not 0.0 < rho_rot < 1.0:
            raise ValueError(f"rho_rot must lie strictly between 0 and 1, got {rho_rot}")
        self.rotation_dims = int(rotation_dims)
        self.rho_rot = float(rho_rot)
        self.learn_rho = bool(learn_rho)
        self.names = ("signal_std", "rho_rot")

    def precompute(self, Xa, Xb=None) -> dict:
        Xa = np.asarray(Xa, dtype=np.float64)
        Xb = Xa if Xb is None else np.asarray(Xb, dtype=np.float64)
        k = self.rotation_dims
        return {"rot": Xa[:, :k] @ Xb[:, :k].T, "trans": Xa[:, k:] @ Xb[:, k:].T}

    def gram(self, pre, values):
        rho = values["rho_rot"]
        G = pre["rot"] * rho
        G += (1.0 - rho) * pre["trans"]
        K = G * values["signal_std"] ** 2
        return K, G

    def grad_contract(self, pre, values, K, state, W, names):
        out = np.empty(len(names))
        for i, name in enumerate(names):
            if name == "signal_std":
                out[i] = 2.0 * fdot(W, K)
            elif name == "rho_rot":
                out[i] = values["signal_std"] ** 2 * values["rho_rot"] * (fdot(W, pre["rot"]) - fdot(W, pre["trans"]))
            else:
                raise KeyError(name)
        return out

    def gram_with_gradient(self, Xa, values, names):
        pre = self.precompute(Xa)
        K, _ = self.gram(pre, values)
        dK = np.empty(K.shape + (len(names),))
        for i, name in enumerate(names):
            if name == "signal_std":
                dK[..., i] = 2.0 * K
            else:
                dK[..., i] = values["signal_std"] ** 2 * values["rho_rot"] * (pre["rot"] - pre["trans"])
        return K, dK

    def diag(self, X, values):
        X = np.asarray(X, dtype=np.float64)
        k = self.rotation_dims
        rho = values["rho_rot"]
        return values["signal_std"] ** 2 * (rho * np.sum(X[:, :k] ** 2, 1) + (1 - rho) * np.sum(X[:, k:] ** 2, 1))

    def default_hyperparameters(self, pre, y):
        # scale so that the prior variance on the data matches var(y)
        g = float(np.mean(np.diag(self.gram(pre, {"rho_rot": self.rho_rot, "signal_std": 1.0})[0])))
        sy = output_scale(y)
        sf = sy / np.sqrt(g) if g > 0 else sy
        return {
            "signal_std": Hyperparameter("signal_std", sf, (1e-4 * sf, 1e3 * sf)),
            "rho_rot": Hyperparameter("rho_rot", self.rho_rot, (0.01, 0.99), fixed=not self.learn_rho),
        }

    def to_dict(self):
        return {"kind": self.kind, "rotation_dims": self.rotation_dims, "rho_rot": self.rho_rot, "learn_rho": self.learn_rho}
