"""rbgp: the rigid-body Gaussian process (Lang & Hirche) for learning and generating rigid-body motion.

Layers, imported one way only::

    geometry -> kernels -> gp -> dynamics -> evaluation
    io, viz: at the edges (readers/writers/model store, recordings/plots)
    cli: thin Typer front end

Conventions are stated once, in :mod:`rbgp_cli.geometry.conventions`.
"""

__version__ = "0.1.0"

__all__ = ["__version__"]
