"""Kernels on poses: the paper's squared exponential on the weighted SE(3) distance (eq. 24), its
chordal variant, the dot-product kernel (eq. 22) and the baselines' kernels (docs/method.md §6)."""

from rbgp_cli.kernels.base import Hyperparameter, Kernel
from rbgp_cli.kernels.dot_product import DotProduct
from rbgp_cli.kernels.squared_exponential import ROTATION_METRICS, SquaredExponential

__all__ = ["Hyperparameter", "Kernel", "SquaredExponential", "DotProduct", "ROTATION_METRICS", "kernel_from_dict"]


def kernel_from_dict(d: dict) -> Kernel:
    """Rebuild a kernel from :meth:`Kernel.to_dict` output (model files)."""
    kind = d.get("kind")
    if kind == SquaredExponential.kind:
        return SquaredExponential(d["metric"], d["rotation_dims"], d["rho_rot"], d["learn_rho"], d.get("time_dims", 0))
    if kind == DotProduct.kind:
        return DotProduct(d["rotation_dims"], d["rho_rot"], d["learn_rho"])
    raise ValueError(f"unknown kernel kind {kind!r}")
