"""BVH in: a joint's world pose by forward kinematics, held against an independent FK written here
(its own reading of the file, 4×4 homogeneous matrices from hand-written elementary rotations,
recursion over the tree) and against scipy's rotations; mixed channel orders; units; errors."""

from __future__ import annotations

import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from rbgp_cli.errors import InputError
from rbgp_cli.io import bvh
from rbgp_cli.io.options import ReadOptions
from rbgp_cli.io.read import detect_format, read_demonstrations
from tests.helpers import rotation_angle_between, rx, ry, rz

ELEMENTARY = {"X": rx, "Y": ry, "Z": rz}


# ------------------------------------------------------------------------------------------------
# the independent forward kinematics

def independent_fk(text: str, joint: str, unit_m: float = 0.01):
    """World poses ``(R (F, 3, 3), p (F, 3) metres)`` of ``joint``: the hierarchy read with regular
    expressions into a tree, each frame's channel values handed out in file order by a running
    counter, and every joint's 4×4 transform ``T_parent_joint`` built from its offset (replaced by
    its position channels) and the product of elementary rotations in its declared order, multiplied
    down the tree recursively."""
    head, motion = re.split(r"^\s*MOTION\s*$", text, flags=re.M)
    tokens = head.split()
    tree = []  # (name, offset, channels, children) nested as dicts

    def block(i, name):
        node = {"name": name, "offset": None, "channels": [], "children": []}
        assert tokens[i] == "{"
        i += 1
        while tokens[i] != "}":
            if tokens[i] == "OFFSET":
                node["offset"] = np.array([float(v) for v in tokens[i + 1 : i + 4]])
                i += 4
            elif tokens[i] == "CHANNELS":
                k = int(tokens[i + 1])
                node["channels"] = tokens[i + 2 : i + 2 + k]
                i += 2 + k
            elif tokens[i] in ("JOINT", "ROOT"):
                child, i = block(i + 2, tokens[i + 1])
                node["children"].append(child)
            elif tokens[i] == "End":
                child, i = block(i + 2, None)
                node["children"].append(child)
            else:
                raise AssertionError(tokens[i])
        return node, i + 1

    i = 1
    while i < len(tokens) and tokens[i] == "ROOT":
        root, i = block(i + 2, tokens[i + 1])
        tree.append(root)
    lines = [ln for ln in motion.strip().splitlines()]
    frame_time = float(lines[1].split(":")[1])
    values = np.array([[float(v) for v in ln.split()] for ln in lines[2:] if ln.strip()])

    def pose(node, vals, counter, parent_t, out):
        trans = node["offset"].copy() if node["offset"] is not None else np.zeros(3)
        rot = np.eye(3)
        for ch in node["channels"]:
            v = vals[counter[0]]
            counter[0] += 1
            if ch.endswith("position"):
                trans["XYZ".index(ch[0])] = v
            else:
                rot = rot @ ELEMENTARY[ch[0]](v)
        t = np.eye(4)
        t[:3, :3], t[:3, 3] = rot, trans
        world = parent_t @ t
        if node["name"] == joint:
            out.append(world.copy())
        for child in node["children"]:
            if child["name"] is not None:
                pose(child, vals, counter, world, out)

    mats = []
    for vals in values:
        out, counter = [], [0]
        for root in tree:
            pose(root, vals, counter, np.eye(4), out)
        assert counter[0] == len(vals)
        mats.append(out[0])
    mats = np.array(mats)
    return mats[:, :3, :3], mats[:, :3, 3] * unit_m, frame_time


def assert_same_poses(tr, rot, pos, atol_m=1e-9, atol_rad=1e-9):
    assert np.max(np.abs(tr.position - pos)) < atol_m
    ang = rotation_angle_between(Rotation.from_quat(tr.quat).as_rotvec(), Rotation.from_matrix(rot).as_rotvec())
    assert np.max(ang) < atol_rad


# ------------------------------------------------------------------------------------------------
# synthetic skeletons: mixed orders, partial channels

MIXED = """HIERARCHY
ROOT hips
{
  OFFSET 1.0 90.0 -2.0
  CHANNELS 6 Zposition Xposition Yposition Yrotation Xrotation Zrotation
  JOINT spine
  {
    OFFSET 0.0 12.0 1.0
    CHANNELS 3 Xrotation Zrotation Yrotation
    JOINT arm
    {
      OFFSET 15.0 2.0 0.0
      CHANNELS 2 Zrotation Xrotation
      JOINT hand
      {
        OFFSET 25.0 0.0 0.5
        CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
        End Site
        {
          OFFSET 8.0 0.0 0.0
        }
      }
    }
  }
  JOINT leg
  {
    OFFSET -9.0 -5.0 0.0
    CHANNELS 3 Yrotation Zrotation Xrotation
  }
}
MOTION
Frames: {frames}
Frame Time: 0.0083333
{rows}
"""


def mixed_bvh(tmp_path, frames=40, seed=0, name="mixed.bvh"):
    rng = np.random.default_rng(seed)
    n_ch = 6 + 3 + 2 + 6 + 3
    vals = rng.uniform(-170, 170, (frames, n_ch))
    vals[:, :3] = rng.normal(0, 50, (frames, 3))  # root positions (Z, X, Y)
    vals[:, 11:14] = np.array([25.0, 0.0, 0.5]) + rng.normal(0, 3, (frames, 3))  # the hand's translations
    rows = "\n".join(" ".join(f"{v:.6f}" for v in r) for r in vals)
    path = tmp_path / name
    path.write_text(MIXED.replace("{frames}", str(frames)).replace("{rows}", rows))
    return path


@pytest.mark.parametrize("joint", ["hips", "spine", "arm", "hand", "leg"])
def test_mixed_channel_orders_match_the_independent_fk(tmp_path, joint):
    path = mixed_bvh(tmp_path)
    assert detect_format(path) == "bvh"
    (tr,) = read_demonstrations([str(path)], ReadOptions(body=joint))
    rot, pos, dt = independent_fk(path.read_text(), joint)
    assert_same_poses(tr, rot, pos)
    assert np.allclose(tr.t, np.arange(40) * 0.0083333) and tr.info["length_unit"] == "cm"


def test_a_joints_rotation_is_its_channels_in_declared_order_as_scipy_composes_them(tmp_path):
    """One joint under the root: the world rotation is R_root · R_joint with each the intrinsic
    product of its channels in file order (scipy: ``from_euler`` with upper-case axes)."""
    path = mixed_bvh(tmp_path, frames=5, seed=3)
    sk = bvh.parse(path.read_text())
    (tr,) = bvh.read(path, ReadOptions(body="spine"))
    m = sk.motion
    root = Rotation.from_euler("YXZ", m[:, 3:6], degrees=True)
    spine = Rotation.from_euler("XZY", m[:, 6:9], degrees=True)
    assert rotation_angle_between(Rotation.from_quat(tr.quat).as_rotvec(), (root * spine).as_rotvec()).max() < 1e-9
    # the root's position channels are named Z, X, Y in that order; the spine's offset turns with the root
    root_p = m[:, [1, 2, 0]]
    assert np.allclose(tr.position, (root_p + root.apply([0.0, 12.0, 1.0])) * 0.01, atol=1e-12)


def test_length_unit_scales_positions_only(tmp_path):
    path = mixed_bvh(tmp_path)
    (cm,) = bvh.read(path, ReadOptions(body="hand"))
    (mm,) = bvh.read(path, ReadOptions(body="hand", length_unit="mm"))
    assert np.allclose(mm.position * 10, cm.position) and np.allclose(mm.quat, cm.quat)
    assert mm.info["length_unit_source"] == "length_unit"


def test_describe_lists_the_joints_and_their_orders(tmp_path):
    d = bvh.describe(mixed_bvh(tmp_path))
    assert d["bodies"] == ["hips", "spine", "arm", "hand", "leg"]
    assert [j["rotation_order"] for j in d["joints"]] == ["YXZ", "XZY", "ZX", "ZYX", "YZX"]
    assert d["frames"] == 40 and np.isclose(d["rate_hz"], 1 / 0.0083333)


# ------------------------------------------------------------------------------------------------
# bad input

def test_errors_are_one_line_and_name_the_file(tmp_path):
    path = mixed_bvh(tmp_path)
    text = path.read_text()
    cases = {
        "no joint named 'hnad'": (text, "hnad"),
        "choose a joint": (text, None),
        "truncated": (text[: len(text) - 200], "hand"),
        "no MOTION section": (text[: text.index("MOTION")], "hand"),
        "unknown channel 'Wrotation'": (text.replace("Zrotation Xrotation\n", "Zrotation Wrotation\n"), "hand"),
        "not closed": (text.replace("    OFFSET -9.0 -5.0 0.0\n    CHANNELS 3 Yrotation Zrotation Xrotation\n  }\n", ""), "hand"),
    }
    for message, (content, body) in cases.items():
        bad = tmp_path / "bad.bvh"
        bad.write_text(content)
        with pytest.raises(InputError) as exc:
            bvh.read(bad, ReadOptions(body=body))
        msg = str(exc.value)
        assert message in msg and str(bad) in msg and "\n" not in msg, msg
    with pytest.raises(InputError, match="did you mean body 'hand'"):
        bvh.read(path, ReadOptions(body="hnad"))


# ------------------------------------------------------------------------------------------------
# the real BVH takes

def wave_files(realdata):
    found = sorted((realdata / "bvh_wave").glob("*.bvh"))
    if not found:
        pytest.skip("no files in bvh_wave")
    return found


@pytest.mark.slow
@pytest.mark.realdata
def test_hand_r_of_every_wave_take_equals_the_readme_derivation(realdata):
    """../shared/realdata/README.md: local translation = position channels, local rotation Rz·Rx·Ry
    from the channels in declared order, chained from the root, cm / 100, the file's frame (Y up)."""
    for path in wave_files(realdata):
        (tr,) = bvh.read(path, ReadOptions(body="Hand_R"))
        rot, pos, dt = independent_fk(path.read_text(), "Hand_R")
        assert_same_poses(tr, rot, pos, atol_m=1e-6, atol_rad=1e-6)
        assert tr.info["chain"][0] == "joint_Root" and tr.info["chain"][-1] == "Hand_R"
        assert np.allclose(tr.t, np.arange(len(tr)) * dt)
        assert 169 <= len(tr) <= 234 and 5.6 <= tr.t[-1] <= 7.8
        # a standing person's right hand: between the hips (~0.9 m) and above the head (< 2.2 m), Y up
        assert 0.5 < np.min(tr.position[:, 1]) and np.max(tr.position[:, 1]) < 2.2


@pytest.mark.realdata
def test_inspect_lists_the_joints_of_a_wave_take(realdata):
    from rbgp_cli.io.inspect import format_inspect, inspect_file

    path = wave_files(realdata)[0]
    d = inspect_file(path)
    assert d["format"] == "bvh" and "Hand_R" in d["description"]["bodies"]
    assert d["description"]["rotation_orders"] == ["ZXY"] and len(d["description"]["bodies"]) == 22
    text = format_inspect(d)
    assert "Hand_R" in text and "ZXY" in text and "still needed" in text


@pytest.mark.slow
@settings(max_examples=60, deadline=None, derandomize=True)
@given(st.lists(st.tuples(st.integers(0, 2), st.integers(0, 10**6), st.integers(1, 40),
                          st.sampled_from(["", "{", "}", " ", "\n", "nan", "1e308", "JOINT", "End Site", "-", "x", "9"])),
                min_size=1, max_size=4))
def test_damaged_bvh_text_reads_or_is_an_input_error(tmp_path_factory, edits):
    path = mixed_bvh(tmp_path_factory.mktemp("fuzz"), frames=6)
    text = path.read_text()
    for op, at, length, token in edits:
        i = at % (len(text) + 1)
        if op == 0:
            text = text[:i] + text[i + length:]
        elif op == 1:
            text = text[:i] + token + text[i:]
        else:
            text = text[:i] + token + text[i + length:]
    path.write_text(text)
    try:
        trajs = bvh.read(path, ReadOptions(body="hand"))
    except InputError as exc:
        assert "\n" not in str(exc) and str(path) in str(exc)
    else:
        assert all(len(t.t) == len(t.quat) == len(t.position) for t in trajs)


def test_a_skeleton_unlike_a_person_in_cm_draws_a_warning_naming_length_unit(tmp_path):
    from rbgp_cli.errors import RbgpWarning

    text = mixed_bvh(tmp_path).read_text()
    small = tmp_path / "small.bvh"  # every offset divided by 100: a skeleton in metres
    small.write_text(re.sub(r"OFFSET ([-\d. ]+)", lambda m: "OFFSET " + " ".join(f"{float(v) / 100:g}" for v in m.group(1).split()), text))
    with pytest.warns(RbgpWarning, match="length_unit"):
        bvh.read(small, ReadOptions(body="hand"))
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error", RbgpWarning)
        bvh.read(small, ReadOptions(body="hand", length_unit="m"))  # said: no warning
        bvh.read(tmp_path / "mixed.bvh", ReadOptions(body="hand"))  # spans ~1.4 m as cm
