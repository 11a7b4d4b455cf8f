"""rbgp: the rigid-body Gaussian process (Lang & Hirche) for learning and generating rigid-body motion.

Layers, imported one way only::

    geometry -> kernels -> gp -> dynamics -> evaluation
    io, viz: at the edges (readers/writers/model store, recordings/plots)
    cli: thin Typer front end

Conventions are stated once, in :mod:`rbgp_cli.geometry.conventions`.

The Python API (:mod:`rbgp_cli.api`, loaded on first use so that ``import rbgp_cli`` stays fast)::

    import rbgp_cli as rbgp
    demos = rbgp.read_demonstrations("sample_data/csv")       # quaternions x, y, z, w; metres; seconds
    gp = rbgp.RigidBodyGP().fit(demos)                          # the options of rbgp train
    res = gp.rollout(demos[0], samples=5)                       # rbgp.Rollout
    print(rbgp.evaluate(res, demos).mean)
"""

__version__ = "0.1.0"

#: the public names, each loaded from rbgp_cli.api on first use
_API = ("read_demonstrations", "RigidBodyGP", "Rollout", "Evaluation", "Crossval", "evaluate", "crossval",
        "start_poses", "train_options")

__all__ = ["__version__", *_API, "SAMPLE_DATA", "InputError", "RbgpError"]


def __getattr__(name):
    if name in _API:
        from rbgp_cli import api

        return getattr(api, name)
    if name == "SAMPLE_DATA":
        from pathlib import Path

        return Path(__file__).resolve().parents[1] / "sample_data"
    if name in ("InputError", "RbgpError"):
        from rbgp_cli import errors

        return getattr(errors, name)
    raise AttributeError(f"module 'rbgp_cli' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(__all__))
