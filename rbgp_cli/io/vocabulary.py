"""The words rbgp's readers understand, in one place: missing-value tokens, unit names and factors,
and the column-name vocabulary of generic CSV/TSV tables.

Every reader (generic CSV and the QTM, Motive and Vicon exports) takes a cell in
:data:`MISSING_TOKENS` as "no value" (a lost frame); lengths convert with :data:`LENGTH_UNITS`, times
with :data:`TIME_UNITS`. The CSV reader (:mod:`rbgp_cli.io.csv`) finds its columns by the names below
(after normalisation: lower case, separators ``_ . - space`` equivalent, a unit suffix removed).
"""

from __future__ import annotations

__all__ = [
    "MISSING_TOKENS", "is_missing", "LENGTH_UNITS", "TIME_UNITS", "CANONICAL_KEYS", "UNIT_TOKENS",
    # CSV column names
    "TIME_NAMES", "TIME_IMPLIED_UNIT", "NSEC_PARTNERS", "FRAME_NAMES", "DEMO_NAMES", "DEMO_SUFFIXES",
    "POS_PREFIXES", "QUAT_PREFIXES", "ROT_AMBIGUOUS", "ROTVEC_PREFIXES", "EULER_AXIS_PREFIXES", "RPY",
    "NUMBERED_PREFIXES", "ROTATION_KINDS", "KIND_ROLES", "KEY_ROLE",
]  # fmt: skip

#: Cell texts that mean "no value", compared after strip + lower case: what spreadsheets, pandas,
#: numpy and the vendor tools write for an empty cell (``NaN``, ``null``, ``#N/A``, ``<NA>``, ...).
MISSING_TOKENS = frozenset({"", "nan", "-nan", "null", "none", "na", "n/a", "<na>", "#n/a", "#na"})

#: metres per unit
LENGTH_UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}


def is_missing(cell: str) -> bool:
    """True when the cell text means "no value" (:data:`MISSING_TOKENS`)."""
    return cell.strip().lower() in MISSING_TOKENS


#: Keys accepted by ``ReadOptions.columns`` (``{KEY: NAME}``).
CANONICAL_KEYS = (
    "t", "x", "y", "z", "qx", "qy", "qz", "qw", "q0", "q1", "q2", "q3",
    "rx", "ry", "rz", "roll", "pitch", "yaw", "frame", "demo",
)  # fmt: skip

#: seconds per unit
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}

#: Unit words in column names -> (quantity, rbgp unit).
UNIT_TOKENS = {
    # length
    "m": ("length", "m"), "meter": ("length", "m"), "meters": ("length", "m"), "metre": ("length", "m"),
    "metres": ("length", "m"), "mm": ("length", "mm"), "millimeter": ("length", "mm"),
    "millimeters": ("length", "mm"), "millimetre": ("length", "mm"), "millimetres": ("length", "mm"),
    "cm": ("length", "cm"), "centimeter": ("length", "cm"), "centimeters": ("length", "cm"),
    "centimetre": ("length", "cm"), "centimetres": ("length", "cm"),
    # time
    "s": ("time", "s"), "sec": ("time", "s"), "secs": ("time", "s"), "second": ("time", "s"),
    "seconds": ("time", "s"), "ms": ("time", "ms"), "msec": ("time", "ms"), "millisecond": ("time", "ms"),
    "milliseconds": ("time", "ms"), "us": ("time", "us"), "µs": ("time", "us"), "usec": ("time", "us"),
    "microsecond": ("time", "us"), "microseconds": ("time", "us"), "ns": ("time", "ns"),
    "nsec": ("time", "ns"), "nanosec": ("time", "ns"), "nanosecond": ("time", "ns"),
    "nanoseconds": ("time", "ns"),
    # angle
    "deg": ("angle", "deg"), "degree": ("angle", "deg"), "degrees": ("angle", "deg"),
    "rad": ("angle", "rad"), "radian": ("angle", "rad"), "radians": ("angle", "rad"),
}  # fmt: skip

# Names (after normalisation and unit extraction) and what they are. Rank 0: exact; rank 1: found as
# a qualified suffix of a longer name (``pose_position_x``); lower rank wins.
TIME_NAMES = {"t", "time", "times", "timestamp", "timestamps", "time_stamp", "stamp", "elapsed",
              "elapsed_time", "time_elapsed"}  # fmt: skip
TIME_IMPLIED_UNIT = {"sec": "s", "secs": "s", "seconds": "s"}
NSEC_PARTNERS = ("nanosec", "nsec", "nsecs", "nanoseconds")
FRAME_NAMES = {"frame", "frames", "frame_number", "frame_no", "frame_num", "frame_index", "frame_idx"}
DEMO_NAMES = {"demo", "demonstration", "trial", "trajectory", "traj", "episode", "sequence"}
DEMO_SUFFIXES = ("", "_id", "_name", "_index", "_idx", "_no", "_number", "_num")
POS_PREFIXES = {"", "p", "pos", "position", "t", "tr", "trans", "translation", "loc", "location", "xyz"}
QUAT_PREFIXES = {"q", "quat", "quaternion", "orientation", "ori", "orient", "qu", "quat_"}
# prefixes whose x, y, z are a quaternion's when a w exists, else the "other" kind
ROT_AMBIGUOUS = {"rot": "euler_axis", "rotation": "euler_axis", "r": "rotvec"}
ROTVEC_PREFIXES = {"rv", "rotvec", "rot_vec", "rotation_vector", "axis_angle", "axisangle", "aa"}
EULER_AXIS_PREFIXES = {"euler", "eul", "euler_angle", "euler_angles", "angle", "ang", "angles"}
RPY = {"roll": "x", "pitch": "y", "yaw": "z"}
NUMBERED_PREFIXES = {"q", "quat", "quaternion", "orientation", "rot", "r"}

ROTATION_KINDS = ("quaternion", "numbered", "rotvec", "euler_axis", "rpy")
KIND_ROLES = {
    "quaternion": ("qx", "qy", "qz", "qw"),
    "numbered": ("qn0", "qn1", "qn2", "qn3"),
    "rotvec": ("rx", "ry", "rz"),
    "euler_axis": ("ex", "ey", "ez"),
    "rpy": ("roll", "pitch", "yaw"),
}
# canonical option key -> internal role
KEY_ROLE = {"q0": "qn0", "q1": "qn1", "q2": "qn2", "q3": "qn3"}
