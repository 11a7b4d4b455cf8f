"""BVH skeletons (Biovision Hierarchy: the CMU collection, the Bandai Namco sets, game and animation
mocap) -> raw :class:`~rbgp_cli.dynamics.trajectory.Trajectory` of one joint's world pose.

The format: a ``HIERARCHY`` section of nested ``ROOT`` / ``JOINT`` blocks, each with an ``OFFSET x y z``
(its origin in the parent's frame, in the rest pose), a ``CHANNELS n name ...`` line and child blocks
(``End Site`` blocks carry only an offset); then ``MOTION``, ``Frames: N``, ``Frame Time: dt`` and N
lines of numbers, one per channel in the order the hierarchy declares them.

A joint's world pose by forward kinematics, frame by frame:

* its local translation is its position channels (``Xposition`` ... by name, in any order) where it
  has them, else its ``OFFSET`` (files that give every joint position channels repeat the offset
  there, and the root's or hips' channels carry the motion: the channels replace the offset, they
  are not added to it);
* its local rotation is the product of its rotation channels **in the order the file declares them**
  (``Zrotation Xrotation Yrotation`` -> ``R = Rz(a) · Rx(b) · Ry(c)``, intrinsic, degrees; files mix
  orders, per joint);
* ``R_world_joint = R_world_parent · R_local``, ``p_world_joint = p_world_parent + R_world_parent ·
  t_local``, from the root (whose parent is the world).

Units: BVH states none. Lengths are read as centimetres unless ``ReadOptions.length_unit`` says
otherwise (cm is the common unit; a warning says when the skeleton's size looks unlike a person in
cm: :data:`REST_EXTENT_M`). Axes: the file's own frame is kept (BVH's convention is Y up; rbgp
does not rotate it). Time: ``t = frame index × Frame Time``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from rbgp_cli.dynamics.trajectory import Trajectory
from rbgp_cli.errors import InputError, closest, warn
from rbgp_cli.io.formats import Format
from rbgp_cli.io.options import ReadOptions
from rbgp_cli.io.vendor import metres_per, quat_from_valid, read_text, reader_guard

__all__ = ["Joint", "Skeleton", "parse", "detect", "read", "describe", "describe_rows", "world_poses", "FORMAT"]

_HINT = "export the take again as BVH (HIERARCHY, then MOTION with Frames and Frame Time)"
CHANNELS = ("Xposition", "Yposition", "Zposition", "Xrotation", "Yrotation", "Zrotation")
_CHANNEL = {c.lower(): c for c in CHANNELS}
#: The unit assumed when ``length_unit`` is not given.
DEFAULT_UNIT = "cm"
#: Read in :data:`DEFAULT_UNIT`, a skeleton whose joints span less or more than this at rest (metres)
#: draws a warning naming ``length_unit`` (a person spans 1.5-2 m; CMU's files, in their own unit, 0.3 m).
REST_EXTENT_M = (0.5, 5.0)


@dataclass
class Joint:
    """One joint: ``name``, ``parent`` (index, -1 for a root), ``offset`` (3,) in file units,
    ``channels`` (names as in :data:`CHANNELS`) and ``first`` (the column of its first channel)."""

    name: str
    parent: int
    offset: np.ndarray
    channels: list = field(default_factory=list)
    first: int = 0

    @property
    def rotation_order(self) -> str:
        """The axes of its rotation channels in file order (``"ZXY"``), ``""`` without any."""
        return "".join(c[0] for c in self.channels if c.endswith("rotation"))


@dataclass
class Skeleton:
    """A parsed BVH file: ``joints`` (in file order, parents first), ``motion`` (F, C) channel values,
    ``frame_time`` (seconds)."""

    joints: list
    motion: np.ndarray
    frame_time: float

    def index(self, name: str) -> int:
        return next(k for k, j in enumerate(self.joints) if j.name == name)

    def chain(self, k: int) -> list[int]:
        """The joint ``k`` and its ancestors, root first."""
        out = []
        while k >= 0:
            out.append(k)
            k = self.joints[k].parent
        return out[::-1]


def detect(head: bytes) -> bool:
    """Auto-detection: the first word of the file is ``HIERARCHY``."""
    text = bytes(head[:64]).decode("utf-8-sig", errors="replace").lstrip("\ufeff \t\r\n")
    return text[:9].upper() == "HIERARCHY"


def _skip_reason(head: bytes, path=None, options=None, complete: bool = False) -> str | None:
    return None if detect(head) else "not a BVH file"


def _float(tok: str, path, line: int, what: str) -> float:
    try:
        return float(tok)
    except ValueError:
        raise InputError(f"{what}: {tok!r} is not a number", path=path, row=line, hint=_HINT) from None


def parse(text: str, path="") -> Skeleton:
    """Parse BVH text into a :class:`Skeleton`; InputError (with the line) for what is not BVH,
    an unknown channel, or a MOTION section with fewer values than ``Frames × channels``."""
    path = str(path)
    lines = text.splitlines()
    toks: list[tuple[str, int]] = []
    motion_line = None
    for no, line in enumerate(lines, 1):
        words = line.split()
        if words and words[0].upper() == "MOTION":
            motion_line = no
            break
        toks += [(w, no) for w in words]
    if not toks or toks[0][0].upper() != "HIERARCHY":
        raise InputError("not a BVH file: it does not start with HIERARCHY", path=path, row=1, hint=_HINT)
    if motion_line is None:
        raise InputError("no MOTION section (the file ends inside the HIERARCHY: truncated?)", path=path,
                         row=len(lines), hint=_HINT)
    joints, n_ch = _hierarchy(toks, path, motion_line)
    names = [j.name for j in joints]
    dup = next((n for n in names if names.count(n) > 1), None)
    if dup is not None:
        raise InputError(f"two joints are named {dup!r}", path=path, hint=_HINT)
    frames, frame_time, values, first_row = _motion(lines, motion_line, path)
    need = frames * n_ch
    if len(values) < need:
        raise InputError(f"the MOTION section holds {len(values)} numbers but Frames: {frames} × {n_ch} channels "
                         f"needs {need} (the file is truncated: {len(values) // max(n_ch, 1)} whole frames)",
                         path=path, row=len(lines), hint="export or copy the take again")
    if len(values) > need:
        raise InputError(f"the MOTION section holds {len(values)} numbers, more than Frames: {frames} × {n_ch} channels "
                         f"({need})", path=path, row=first_row + frames, hint="check the Frames line")
    motion = np.asarray(values, float).reshape(frames, n_ch) if n_ch else np.zeros((frames, 0))
    return Skeleton(joints=joints, motion=motion, frame_time=frame_time)


def _hierarchy(toks, path: str, motion_line: int) -> tuple[list, int]:
    """The joints of the HIERARCHY tokens ``toks`` ((word, line) after ``HIERARCHY``) and the number
    of channels; InputError for what does not fit the grammar."""
    joints: list[Joint] = []
    stack: list[int] = []  # joint indices (-2 for an End Site)
    pending: tuple[str, int] | None = None  # name and parent of a block whose '{' is next
    n_ch = 0
    i = 1
    while i < len(toks):
        word, no = toks[i]
        key = word.upper()
        if key in ("ROOT", "JOINT"):
            if i + 1 >= len(toks):
                raise InputError(f"{word} without a name", path=path, row=no, hint=_HINT)
            parent = next((s for s in reversed(stack) if s >= 0), -1) if key == "JOINT" else -1
            if key == "JOINT" and not stack:
                raise InputError("JOINT outside any ROOT block", path=path, row=no, hint=_HINT)
            pending = (toks[i + 1][0], parent)
            i += 2
        elif key == "END":  # End Site
            pending = ("", -2)
            i += 2
        elif word == "{":
            if pending is None:
                raise InputError("'{' without ROOT, JOINT or End Site before it", path=path, row=no, hint=_HINT)
            name, parent = pending
            if parent == -2:
                stack.append(-2)
            else:
                joints.append(Joint(name=name, parent=parent, offset=np.zeros(3)))
                stack.append(len(joints) - 1)
            pending = None
            i += 1
        elif word == "}":
            if not stack:
                raise InputError("'}' without a block to close", path=path, row=no, hint=_HINT)
            stack.pop()
            i += 1
        elif key == "OFFSET":
            vals = [_float(t, path, n, "OFFSET") for t, n in toks[i + 1 : i + 4]]
            if len(vals) < 3:
                raise InputError("OFFSET needs three numbers", path=path, row=no, hint=_HINT)
            if stack and stack[-1] >= 0:
                joints[stack[-1]].offset = np.array(vals)
            i += 4
        elif key == "CHANNELS":
            if not stack or stack[-1] < 0:
                raise InputError("CHANNELS outside a ROOT or JOINT block", path=path, row=no, hint=_HINT)
            count = int(_float(toks[i + 1][0], path, no, "CHANNELS count")) if i + 1 < len(toks) else -1
            names = [t for t, _ in toks[i + 2 : i + 2 + count]]
            if count < 0 or len(names) < count:
                raise InputError("CHANNELS line ends early", path=path, row=no, hint=_HINT)
            unknown = [c for c in names if c.lower() not in _CHANNEL]
            if unknown:
                raise InputError(f"unknown channel {unknown[0]!r} (channels are {', '.join(CHANNELS)})", path=path,
                                 row=no, hint=_HINT)
            j = joints[stack[-1]]
            j.channels = [_CHANNEL[c.lower()] for c in names]
            j.first = n_ch
            n_ch += count
            i += 2 + count
        else:
            raise InputError(f"unexpected {word!r} in the HIERARCHY", path=path, row=no, hint=_HINT)
    if stack:
        raise InputError(f"{len(stack)} block(s) of the HIERARCHY are not closed", path=path, row=motion_line,
                         hint=_HINT)
    if not joints:
        raise InputError("the HIERARCHY has no ROOT joint", path=path, row=motion_line, hint=_HINT)
    return joints, n_ch


def _motion(lines, motion_line: int, path):
    """``(frames, frame_time, values, first data line)`` of the MOTION section."""
    frames = frame_time = None
    k = motion_line
    while k < len(lines) and (frames is None or frame_time is None):
        line = lines[k].strip()
        k += 1
        if not line:
            continue
        low = line.lower()
        if low.startswith("frames:"):
            frames = int(_float(line.split(":", 1)[1].strip() or "x", path, k, "Frames"))
        elif low.startswith("frame time:"):
            frame_time = _float(line.split(":", 1)[1].strip() or "x", path, k, "Frame Time")
        else:
            raise InputError(f"expected 'Frames:' and 'Frame Time:' after MOTION, got {line[:40]!r}", path=path,
                             row=k, hint=_HINT)
    if frames is None or frame_time is None:
        raise InputError("the MOTION section has no 'Frames:' or 'Frame Time:' line (truncated?)", path=path,
                         row=len(lines), hint=_HINT)
    if frames < 1 or not frame_time > 0:
        raise InputError(f"Frames: {frames}, Frame Time: {frame_time:g}: need at least one frame and a positive "
                         "frame time", path=path, row=k, hint=_HINT)
    data = " ".join(lines[k:]).split()
    try:
        values = np.array(data, dtype=float)
    except ValueError:
        for no in range(k, len(lines)):
            for tok in lines[no].split():
                _float(tok, path, no + 1, "MOTION value")
        raise  # pragma: no cover
    return frames, frame_time, values, k + 1


def _local(sk: Skeleton, j: Joint):
    """Local rotations (F, 3, 3) and translations (F, 3), file units, of one joint per frame."""
    from scipy.spatial.transform import Rotation as R

    f = len(sk.motion)
    trans = np.tile(j.offset, (f, 1))
    rot_axes, rot_cols = [], []
    for c, name in enumerate(j.channels):
        col = sk.motion[:, j.first + c]
        if name.endswith("position"):
            trans[:, "XYZ".index(name[0])] = col  # position channels replace the offset
        else:
            rot_axes.append(name[0])
            rot_cols.append(col)
    if rot_axes:
        # intrinsic rotations in the declared order: R = R_a1(v1) · R_a2(v2) · R_a3(v3)
        rot = R.from_euler("".join(rot_axes), np.stack(rot_cols, axis=1), degrees=True).as_matrix()
    else:
        rot = np.tile(np.eye(3), (f, 1, 1))
    return rot, trans


def world_poses(sk: Skeleton, joint: int):
    """``(R_world_joint (F, 3, 3), p_world_joint (F, 3))`` of joint index ``joint`` by forward kinematics
    (file units), composing the local transforms of its chain from the root."""
    f = len(sk.motion)
    rot_w = np.tile(np.eye(3), (f, 1, 1))
    pos_w = np.zeros((f, 3))
    for k in sk.chain(joint):
        rot_l, trans_l = _local(sk, sk.joints[k])
        pos_w = pos_w + np.einsum("fij,fj->fi", rot_w, trans_l)
        rot_w = rot_w @ rot_l
    return rot_w, pos_w


def _joint(sk: Skeleton, body: str | None, path) -> list[int]:
    names = [j.name for j in sk.joints]
    if body is None:
        raise InputError(f"choose a joint: the skeleton has {len(names)} (" + ", ".join(names[:12])
                         + (", ..." if len(names) > 12 else "") + ")", path=path,
                         hint="use body JOINT, e.g. body Hand_R; `rbgp inspect FILE` lists them", param="body")
    if body == "all":
        return list(range(len(names)))
    if body in names:
        return [names.index(body)]
    folded = [k for k, n in enumerate(names) if n.lower() == body.lower()]
    if len(folded) == 1:
        return folded
    guess = closest(body, names)
    raise InputError(f"no joint named {body!r} in the skeleton ({len(names)} joints)", path=path,
                     hint=(f"did you mean body {guess!r}? " if guess else "") + "`rbgp inspect FILE` lists them",
                     param="body")


def _unit(sk: Skeleton, options: ReadOptions, path) -> tuple[str, str, float]:
    if options.length_unit:
        unit, source = options.length_unit, "length_unit"
    else:
        unit, source = DEFAULT_UNIT, "assumed: BVH states no unit"
    scale = metres_per(unit, path=path, hint="use length_unit m|cm|mm")
    if not options.length_unit:
        height = _rest_extent(sk) * scale
        if height > 0 and not REST_EXTENT_M[0] <= height <= REST_EXTENT_M[1]:
            warn(f"read as cm, the skeleton spans {height:.3g} m at rest; if its unit is not cm, give it with "
                 "length_unit", path=path, param="length_unit")
    return unit, source, scale


def _rest_extent(sk: Skeleton) -> float:
    """The largest distance between two joints in the rest pose (offsets only), file units."""
    pos = np.zeros((len(sk.joints), 3))
    for k, j in enumerate(sk.joints):
        pos[k] = (pos[j.parent] if j.parent >= 0 else 0.0) + j.offset
    return float(np.max(np.linalg.norm(pos[:, None] - pos[None], axis=-1))) if len(pos) > 1 else 0.0


@reader_guard("a BVH file", _HINT)
def read(path, options: ReadOptions | None = None) -> list[Trajectory]:
    """The world pose of the joint ``options.body`` (``"all"``: every joint) per frame.

    Returns raw trajectories: ``t = frame × Frame Time`` seconds, quaternions x, y, z, w (joint ->
    the file's world frame), positions in metres (the file's values in ``length_unit``, cm by default).
    """
    options = options or ReadOptions()
    path = str(path)
    sk = parse(read_text(path), path)
    chosen = _joint(sk, options.body, path)
    unit, unit_source, scale = _unit(sk, options, path)
    from scipy.spatial.transform import Rotation as R

    t = np.arange(len(sk.motion)) * sk.frame_time
    out = []
    for k in chosen:
        rot, pos = world_poses(sk, k)
        good = np.all(np.isfinite(rot), axis=(1, 2)) & np.all(np.isfinite(pos), axis=1)
        quat = quat_from_valid(good, R.from_matrix, rot)
        pos = np.where(good[:, None], pos * scale, np.nan)
        orders = sorted({sk.joints[c].rotation_order for c in sk.chain(k)} - {""})
        out.append(Trajectory(t=t, quat=quat, position=pos, name=sk.joints[k].name, source=path, info={
            "format": "bvh", "body": sk.joints[k].name, "chain": [sk.joints[c].name for c in sk.chain(k)],
            "length_unit": unit, "length_unit_source": unit_source, "up_axis": "the file's own (BVH's convention: Y)",
            "rate_hz": 1.0 / sk.frame_time, "frame_time_s": sk.frame_time, "time_source": "frame × Frame Time",
            "rotation_source": "forward kinematics (each joint's rotation matrix from its Euler channels in "
                               "declared order: " + ", ".join(orders) + ")",
            "lost_frames": int((~good).sum()),
        }))
    return out


def _read_all(path, options: ReadOptions | None = None) -> list[Trajectory]:
    """For ``rbgp inspect``: the named joint, or none (a skeleton has many; the description lists them)."""
    options = options or ReadOptions()
    return read(path, options) if options.body is not None else []


@reader_guard("a BVH file", _HINT)
def describe(path, options: ReadOptions | None = None) -> dict:
    """Plain data for ``rbgp inspect``: the joints (name, parent, channels, rotation order), frames,
    frame time, the rotation orders used, units and axes."""
    options = options or ReadOptions()
    path = str(path)
    sk = parse(read_text(path), path)
    unit = options.length_unit or DEFAULT_UNIT
    return {
        "format": "bvh",
        "joints": [{"name": j.name, "parent": sk.joints[j.parent].name if j.parent >= 0 else None,
                    "channels": list(j.channels), "rotation_order": j.rotation_order} for j in sk.joints],
        "bodies": [j.name for j in sk.joints],
        "frames": int(len(sk.motion)),
        "frame_time_s": sk.frame_time,
        "rate_hz": 1.0 / sk.frame_time,
        "duration_s": (len(sk.motion) - 1) * sk.frame_time,
        "rotation_orders": sorted({j.rotation_order for j in sk.joints} - {""}),
        "length_unit": unit,
        "length_unit_source": "length_unit" if options.length_unit else "assumed: BVH states no unit",
        "rest_extent_m": _rest_extent(sk) * metres_per(unit, path=path),
        "needs": [],
    }


def _needs(desc: dict, options) -> list[str]:
    if options.body is None and desc.get("bodies"):
        return [f"body JOINT (the skeleton has {len(desc['bodies'])} joints)"]
    return []


def describe_rows(desc: dict) -> list[str]:
    """The text rows of ``rbgp inspect`` for :func:`describe`'s result."""
    from rbgp_cli.io.inspect import fmt_num, rate_text, text_row

    joints = desc.get("joints") or []
    roots = [j["name"] for j in joints if j["parent"] is None]
    rows = [text_row("frames", f"{desc['frames']} at {rate_text(desc)} (Frame Time {desc['frame_time_s']:g} s), "
                               f"{fmt_num(desc['duration_s'], ' s')}")]
    rows.append(text_row("joints", f"{len(joints)} from {', '.join(roots)}: " + ", ".join(j["name"] for j in joints)))
    orders = desc.get("rotation_orders") or []
    by_order = {o: [j["name"] for j in joints if j["rotation_order"] == o] for o in orders}
    if len(orders) == 1:
        rot = f"Euler {orders[0]} (intrinsic, degrees) for every joint with rotation channels"
    else:
        rot = "; ".join(f"{o} for {', '.join(names[:4])}{' ...' if len(names) > 4 else ''}" for o, names in by_order.items())
    rows.append(text_row("rotation", rot or "no rotation channels"))
    with_pos = sum(1 for j in joints if any(c.endswith("position") for c in j["channels"]))
    rows.append(text_row("translation", f"position channels for {with_pos} of {len(joints)} joints (they replace the "
                                        "OFFSET), OFFSET for the others"))
    rows.append(text_row("units", f"{desc['length_unit']} ({desc['length_unit_source']}; the skeleton spans "
                                  f"{fmt_num(desc.get('rest_extent_m'), ' m')} at rest), the file's axes (BVH: Y up)"))
    return rows


FORMAT = Format(
    name="bvh", title="BVH skeleton", detect=detect, read=read, describe=describe, describe_rows=describe_rows,
    skip_reason=_skip_reason, read_all=_read_all, needs=_needs, suffix=".bvh",
    honours=("body",),
)
