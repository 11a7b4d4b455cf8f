"""Options that tell the readers how to interpret a file. One dataclass, shared by every format.

All fields default to "decide from the file"; when the file does not decide and the choice matters,
the reader raises :class:`rbgp_cli.errors.InputError` naming the option that decides it.
"""

from __future__ import annotations

from dataclasses import dataclass

from rbgp_cli.io.vocabulary import LENGTH_UNITS

__all__ = ["ReadOptions", "LENGTH_UNITS"]  # FORMATS: module __getattr__ (the registry's choices)


def __getattr__(name):
    if name == "FORMATS":  # the values of ``format``: "auto" and the registered formats
        from rbgp_cli.io.formats import choices

        return choices()
    raise AttributeError(name)


@dataclass(frozen=True)
class ReadOptions:
    """How to read demonstrations (CLI flags of the same names).

    format : ``auto`` (sniffs the content) or a format name (:func:`rbgp_cli.io.formats.names`).
    columns : explicit column mapping for CSV, e.g. ``{"t": "stamp", "qx": "ox", ...}``; keys among
        t, x, y, z, qx, qy, qz, qw, rx, ry, rz, roll, pitch, yaw, demo.
    quat_order : ``xyzw`` or ``wxyz``, for columns named q0..q3 (or quaternion columns in a vendor
        export whose order is not stated); for CSV columns named qx, qy, qz, qw it overrides the
        names: the four columns, in file order, are taken in this order.
    euler_order : scipy-style sequence (``xyz`` extrinsic, ``XYZ`` intrinsic) for Euler columns.
    degrees : Euler angles in degrees (None: from the file's header/unit suffixes, else radians).
    length_unit : ``m``, ``cm`` or ``mm`` (None: from the file, else metres with a hint if values
        look like mm).
    time_unit : ``s``, ``ms``, ``us``, ``ns`` (None: from the column name, else seconds).
    rate : sample rate in Hz when there is no time column.
    topic : MCAP topic; frame : child frame (TF); time_source : ``header`` or ``log``.
    body : rigid body / segment name in vendor exports with several bodies.
    rotation : Vicon RX,RY,RZ meaning: ``helical`` (axis-angle, default) or ``euler``.
    file_order : the order the files are read in, which is the demonstrations' recording order
        (:func:`rbgp_cli.io.read.list_sources`; docs/data.md): ``given`` (a folder's or a pattern's files
        in natural name order, files named one by one as given), ``name`` (every file in natural name
        order, whatever order they were given in, e.g. by a shell glob, which sorts take_10 before
        take_2) or ``mtime`` (every file by its modification time, oldest first; ties by name).

    How the samples read are cut into demonstrations (:func:`rbgp_cli.dynamics.prepare.prepare_all`):

    split_gap : seconds; a step with no sample longer than this splits a demonstration (None: 20 ×
        its median step and at least 2 s; ``inf``: never).
    crop_from, crop_to : seconds since each take's first sample; keep only the samples in between.
    split_at_rest : cut each take into repetitions separated by rests (speed below ``rest_speed``
        m/s, angular speed below 0.3 rad/s, for at least ``rest_time`` s).
    """

    format: str = "auto"
    columns: dict | None = None
    quat_order: str | None = None
    euler_order: str | None = None
    degrees: bool | None = None
    length_unit: str | None = None
    time_unit: str | None = None
    rate: float | None = None
    topic: str | None = None
    frame: str | None = None
    time_source: str = "header"
    body: str | None = None
    rotation: str | None = None
    file_order: str = "given"
    split_gap: float | None = None
    crop_from: float | None = None
    crop_to: float | None = None
    split_at_rest: bool = False
    rest_speed: float | None = None
    rest_time: float | None = None

    def prepare_kwargs(self) -> dict:
        """Keyword arguments of :func:`rbgp_cli.dynamics.prepare.prepare_all` (crop, split_gap, rest)."""
        out: dict = {"split_gap": self.split_gap}
        if self.crop_from is not None or self.crop_to is not None:
            out["crop"] = (self.crop_from, self.crop_to)
        if self.split_at_rest:
            from rbgp_cli.dynamics.prepare import RestSplit

            kw = {k: v for k, v in (("speed", self.rest_speed), ("min_rest", self.rest_time)) if v is not None}
            out["rest"] = RestSplit(**kw)
        return out
